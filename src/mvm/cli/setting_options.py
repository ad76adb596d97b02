"""Command-line options of settings: an option that sets one field of a settings dataclass takes
its type, its bounds, its help text and the default it shows from the field's declaration
(:func:`mvm.core.config.setting` and the ``#:`` comment above it), the one place they are written.

The dataclass is named ``module:class`` and imported only when the option is read or its help is
printed, so that ``mvm --help`` does not import the video stages (OpenCV) or the simulator.
"""
from __future__ import annotations

import dataclasses
import functools
import importlib

import click

#: The settings of the video stages, named as :func:`setting_option` takes them.
FRAMES = "mvm.video.frames:FrameOptions"
SFM = "mvm.video.sfm:SfmOptions"
DETECT = "mvm.video.detect:DetectOptions"


#: Units of a comment (``[unit]``) that say nothing in an option's help.
UNSHOWN_UNITS = {"1", "-", "bool", "name", "path"}


@functools.cache
def declaration(settings: str, name: str) -> tuple[dataclasses.Field, str, str | None]:
    """The field ``name`` of the settings dataclass ``settings`` (``module:class``), its
    comment without its unit, and its unit (None: none worth showing)."""
    from mvm.settings.reference import field_docs, split_unit

    module, cls_name = settings.split(":")
    cls = getattr(importlib.import_module(module), cls_name)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    text, unit = split_unit(field_docs(cls).get(name, ""))
    return fields[name], text, None if unit in UNSHOWN_UNITS else unit


class SettingType(click.ParamType):
    """The type of the setting ``name`` of ``settings``: one of its choices, or a number within
    its bounds (:class:`mvm.cli.common.Number`), or text."""

    def __init__(self, settings: str, name: str):
        self.settings, self.setting = settings, name
        self.name = name

    @functools.cached_property
    def _inner(self) -> click.ParamType:
        from mvm.cli.common import Number
        from mvm.core.config import setting_kind

        field, _, _ = declaration(self.settings, self.setting)
        bounds = field.metadata.get("bounds")
        if bounds is not None and bounds.choices is not None and all(isinstance(c, str) for c in bounds.choices):
            return click.Choice([str(c) for c in bounds.choices])
        kind, _ = setting_kind(field)
        if kind in ("int", "float"):
            number = Number(int if kind == "int" else float)
            number.bounds = bounds if bounds is not None else number.bounds
            return number
        return click.STRING

    def convert(self, value, param, ctx):
        return self._inner.convert(value, param, ctx)

    def get_metavar(self, param, ctx=None):
        return self._inner.get_metavar(param, ctx) or self.name.upper()


def _range(option_type: click.ParamType) -> str | None:
    """The range of a command's own bounds narrower than the declaration's (``1-30``), or None."""
    bounds = getattr(option_type, "bounds", None)
    if isinstance(option_type, SettingType) or bounds is None or bounds.ge is None or bounds.le is None:
        return None
    return f"{bounds.ge:g}-{bounds.le:g}"


class SettingOption(click.Option):
    """An option of one setting; its help is the field's comment, its unit and its default (with
    the command's narrower range, where it has one), read when the help is printed. The option's
    own default is None: the settings file's value, else the field's default, applies where it
    is not given."""

    def __init__(self, param_decls, settings: str, setting: str, type: click.ParamType | None = None, **kwargs):
        kwargs.setdefault("default", None)
        super().__init__(param_decls, type=type or SettingType(settings, setting), **kwargs)
        self.settings, self.setting = settings, setting

    def get_help_record(self, ctx):
        if self.help is None:
            from mvm.settings.reference import field_default

            field, text, unit = declaration(self.settings, self.setting)
            default = field_default(field)
            notes = [n for n in (unit, _range(self.type), None if default is None else f"default: {default}") if n]
            self.help = f"{text.rstrip('.')} ({', '.join(notes)})." if notes else text
        return super().get_help_record(ctx)


def setting_option(settings: str, name: str, *param_decls: str, **kwargs):
    """The ``click.option`` of the setting ``name`` of the settings dataclass ``settings``
    (``module:class``): ``setting_option("mvm.rig.options:RigOptions", "smoothing", "--smoothing")``.
    ``help=`` replaces the field's comment where the command says it better; ``type=`` (a
    :class:`~mvm.cli.common.Number`) replaces the declaration's bounds where the command's are
    deliberately narrower (``mvm simulate --people``), its range then shown in the help."""
    decls = param_decls or ("--" + name.replace("_", "-"),)
    return click.option(*decls, name, cls=SettingOption, settings=settings, setting=name, **kwargs)
