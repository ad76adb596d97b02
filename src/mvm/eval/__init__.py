"""The experiments: the demo's evaluation, the paper's benchmarks (tables and sweeps), the crowd
benchmark, the Panoptic evaluation and C_var of reconstructed scenes (Table 5). They simulate or
read scenes, reconstruct them and score them with :mod:`mvm.metrics`."""
