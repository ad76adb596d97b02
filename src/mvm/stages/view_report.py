"""``report``: the offline HTML page of a reconstruction (:func:`mvm.report.write_report` of a
scene, :func:`mvm.report.rig_page.write_rig_report` of a rig), ``<output>/report.html`` or
``-o``, its record beside it (:mod:`mvm.stages.view`); kept while what it is drawn from and its
settings are unchanged."""
from __future__ import annotations

from pathlib import Path

from mvm.io.layout import REPORT_PAGE
from mvm.stages import view
from mvm.stages.stage import Done, Stage, present

#: The stage in the reasons of a rerun.
TITLE = "the report"


def _page(job: view.ViewJob) -> Path:
    return Path(job.out) if job.out is not None else job.out_dir / REPORT_PAGE


def _settings(job: view.ViewJob) -> dict:
    return {"calib": str(job.calib) if job.calib else None} if job.rig else {"frames": job.frames}


def _run(job: view.ViewJob, force: bool) -> Done:
    """``Done.result``: the page's path."""
    from mvm.io.provenance import produce

    page, inputs = _page(job), view.view_inputs(job)
    view.check_record_name(page, inputs, TITLE)

    def make(why: str, hashed: dict) -> Path:
        if job.rig:
            from mvm.report.rig_page import write_rig_report

            path = write_rig_report(view.load_rig_view(job), view.input_paths(inputs), job.out)
            view.list_in_output_set(job, path)
            return path
        from mvm.report import write_report

        return write_report(Path(job.folder), output=job.output, frames=job.frames, path=job.out)

    path, why = produce(page, TITLE, inputs, _settings(job), make, lambda: page, force=force)
    return Done(path, why)


STAGE = Stage("report", TITLE, (), _page, view.view_inputs, _settings, lambda job: present(_page(job)), _run,
              applies=view.not_reconstructed)
