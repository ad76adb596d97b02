"""The ``mvm`` process: native libraries' output goes to the log unless ``-v``, and SIGINT or
SIGTERM ends a command in one line, even after pycolmap (glog) installed its own handlers."""
import os
import signal
import subprocess
import sys
import textwrap

import pytest

from helpers import REPO

pytestmark = pytest.mark.skipif(os.name != "posix", reason="POSIX signals and file descriptors")

#: A command that imports pycolmap, writes to file descriptor 2 past Python, says it is ready and waits.
SCRIPT = textwrap.dedent("""
    import os, sys, time
    import click
    import importlib
    cli = importlib.import_module("mvm.cli.main")
    from mvm.cli.common import command

    @command("wait")
    def wait():
        import pycolmap  # noqa: F401   installs glog's failure signal handler
        import cv2  # noqa: F401
        os.write(2, b"native noise from a library\\n")
        click.echo("mvm's own warning", err=True)
        print("ready", flush=True)
        time.sleep(float(os.environ.get("WAIT_S", "30")))

    cli._Commands.get_command = lambda self, ctx, name: wait
    cli.main(sys.argv[1:], prog_name="mvm")
""")


def _start(*args, wait_s: float = 30):
    env = {**os.environ, "PYTHONPATH": str(REPO / "src"), "WAIT_S": str(wait_s)}
    process = subprocess.Popen([sys.executable, "-c", SCRIPT, *args, "wait"], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, env=env, text=True)
    assert process.stdout.readline() == "ready\n"
    return process


@pytest.mark.parametrize("signum, status", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_a_signal_ends_the_command_in_one_line(signum, status):
    process = _start()
    process.send_signal(signum)
    _, stderr = process.communicate(timeout=30)
    assert process.returncode == status
    assert stderr == f"mvm's own warning\nmvm: interrupted ({signal.Signals(signum).name})\n"


def test_native_output_goes_to_the_log_unless_verbose():
    process = _start(wait_s=0)
    _, stderr = process.communicate(timeout=30)
    assert process.returncode == 0 and stderr == "mvm's own warning\n"
    process = _start("-v", wait_s=0)
    _, stderr = process.communicate(timeout=30)
    assert process.returncode == 0 and "native noise from a library" in stderr
    process = _start("-vv", wait_s=0)
    _, stderr = process.communicate(timeout=30)
    assert "native noise from a library" in stderr


def test_a_broken_video_is_one_line(tmp_path):
    video = tmp_path / "broken.mp4"
    video.write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(200))
    result = subprocess.run([sys.executable, "-m", "mvm", "frames", str(video), "-o", str(tmp_path / "s")],
                            capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(REPO / "src")},
                            timeout=120)
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and result.stderr.startswith("mvm: error: "), result.stderr
