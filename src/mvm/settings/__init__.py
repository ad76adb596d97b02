"""Settings, read and printed: every command's settings are a frozen dataclass declared with
:func:`mvm.core.config.setting` (its default, bounds and ``#:`` comment); this package reads them
from a TOML file and ``--set`` overrides (:mod:`mvm.settings.tables`), prints the reference file
of every table and checks a file (:mod:`mvm.settings.reference`)."""
