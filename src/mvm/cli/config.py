"""``mvm config``: the reference settings file of every command, and its check."""
from __future__ import annotations

import click

from mvm.cli.common import command


@command("config")
@click.option("--check", "check", type=click.Path(), default=None, metavar="FILE.toml",
              help="Check this settings file (tables, keys, types and ranges) without running anything.")
def config_cmd(check: str | None) -> None:
    """Print every setting of every command with its default, unit and allowed values, as a
    commented TOML file to copy and edit (pass it with --config); or check such a file."""
    if check is None:
        from mvm.settings.reference import reference_toml

        click.echo(reference_toml(), nl=False)
        return
    from mvm.settings.reference import check_settings_file

    tables = check_settings_file(check)
    click.echo(f"{check}: OK ({', '.join(f'[{t}]' for t in tables) or 'no settings'})")
