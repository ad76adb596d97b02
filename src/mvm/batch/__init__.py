"""Whole data sets: every clip of a root through the pipeline's stages, on a local process
pool or Ray, recorded in an SQLite manifest so that a rerun does only what is not done."""
from mvm.batch.clips import Clip, discover_clips
from mvm.batch.manifest import Manifest
from mvm.batch.runner import BatchSummary, merge_training_set, parse_stages, run_batch
from mvm.batch.stages import STAGES, BatchOptions, StageResult, run_stage
from mvm.batch.status import Status, batch_status, dataset_statistics

__all__ = ["Clip", "discover_clips", "Manifest", "BatchSummary", "merge_training_set", "parse_stages", "run_batch",
           "STAGES", "BatchOptions", "StageResult", "run_stage", "Status", "batch_status", "dataset_statistics"]
