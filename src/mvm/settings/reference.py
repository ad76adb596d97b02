"""The settings of every command: the settings dataclass of each table of a settings file
(:data:`mvm.settings.tables.TABLES`), the reference file (``mvm config``), one TOML table per settings object,
each key with its default and a comment
giving what it does, its unit and its allowed values; and the check of such a file.

Everything is generated from the settings dataclasses: the fields, their defaults and their
:class:`~mvm.core.config.Bounds`, and the ``#:`` comment above each field in its module's source
(the text; its unit is the ``[...]`` at its end).
"""
from __future__ import annotations

import ast
import dataclasses
import importlib
import inspect
import json
import math
import re
import textwrap
from pathlib import Path

from mvm.core.config import Bounds, setting_kind, settings_from
from mvm.errors import InputError
from mvm.settings.tables import TABLES, read_tables

_WIDTH = 96


def table_class(table: str) -> type:
    """The settings dataclass of ``table`` (:data:`mvm.settings.tables.TABLES`)."""
    module, name = TABLES[table][0].split(":")
    return getattr(importlib.import_module(module), name)


def field_docs(cls) -> dict[str, str]:
    """``{field: text}``: the ``#:`` comment lines above each field of ``cls`` in its source,
    joined."""
    lines, _ = inspect.getsourcelines(cls)
    tree = ast.parse(textwrap.dedent("".join(lines)))
    body = tree.body[0].body
    docs = {}
    for node in body:
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            comment = []
            row = node.lineno - 2                                   # the line above, 0-based
            while row >= 0 and lines[row].strip().startswith("#:"):
                comment.insert(0, lines[row].strip()[2:].strip())
                row -= 1
            if comment:
                docs[node.target.id] = " ".join(comment)
    return docs


def split_unit(text: str) -> tuple[str, str | None]:
    """``("sentence", "unit")`` of a field's comment ending in ``[unit]``."""
    match = re.match(r"^(.*?)\s*\[([^\[\]]*)\]\s*$", text, re.S)
    return (match.group(1), match.group(2)) if match else (text, None)


def allowed(field: dataclasses.Field) -> str:
    """The allowed values of a settings field, in words: its type, range or choices."""
    kind, optional = setting_kind(field)
    bounds: Bounds = field.metadata.get("bounds", Bounds())
    if bounds.choices is not None:
        text = "one of " + ", ".join(toml_value(c) for c in bounds.choices)
    else:
        limits = [f"{op} {_number(limit)}" for limit, op in ((bounds.ge, ">="), (bounds.gt, ">"),
                                                             (bounds.le, "<="), (bounds.lt, "<")) if limit is not None]
        text = " ".join(filter(None, [kind or "", "(" + ", ".join(limits) + ")" if limits else ""]))
        if bounds.odd:
            text += ", odd"
    return ", or ".join(filter(None, [text, "unset" if optional else ""]))


def _number(value) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def toml_value(value) -> str:
    """``value`` written as TOML."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else ("nan" if value != value else ("inf" if value > 0 else "-inf"))
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, (tuple, list)):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    raise TypeError(f"no TOML for {value!r}")


def field_default(field: dataclasses.Field):
    """The default of a settings field (its factory's value for a nested settings object)."""
    if field.default is not dataclasses.MISSING:
        return field.default
    return field.default_factory()


def _comment(text: str) -> list[str]:
    return textwrap.wrap(text, _WIDTH - 2, initial_indent="# ", subsequent_indent="# ") if text else []


def table_lines(name: str, cls, values=None) -> list[str]:
    """The lines of the table ``name`` of the settings dataclass ``cls`` (sub-tables of nested
    settings after its keys); ``values``: the instance whose values are written (default: the
    defaults)."""
    tables = {settings.split(":")[1]: t for t, (settings, _) in TABLES.items()}
    docs = field_docs(cls)
    lines, nested = [f"[{name}]"], []
    for field in dataclasses.fields(cls):
        value = getattr(values, field.name) if values is not None else field_default(field)
        text, unit = split_unit(docs.get(field.name, ""))
        if dataclasses.is_dataclass(value):
            if type(value).__name__ in tables:
                lines += [f"# {field.name}: the [{tables[type(value).__name__]}] table."]
            else:
                nested.append((field.name, value, text))
            continue
        lines.append("")
        lines += _comment(text)
        lines += _comment("; ".join(filter(None, [f"unit: {unit}" if unit and unit not in ("-", "bool") else "",
                                                   f"allowed: {allowed(field)}" if allowed(field) else ""])))
        if value is None:
            lines.append(f"# {field.name} =    (unset)")
        elif isinstance(value, tuple) and value and dataclasses.is_dataclass(value[0]):
            lines.append(f"# {field.name}: {len(value)} table(s)")
        else:
            lines.append(f"{field.name} = {toml_value(value)}")
    for key, value, text in nested:
        lines += ["", *_comment(text)] + table_lines(f"{name}.{key}", type(value), value)
    return lines


def reference_toml(tables: tuple[str, ...] | None = None) -> str:
    """The reference settings file: every table of :data:`TABLES` (or of ``tables``), each key
    with its default and a comment. It passes :func:`check_settings_file`, and each table read
    back gives the defaults."""
    out = ["# Every setting of every mvm command with its default (printed by `mvm config`).",
           "# Copy it, keep what you change, pass it with --config; `mvm config --check FILE` checks it.",
           "# A key left out keeps its default; a key shown as `# key =    (unset)` has none."]
    for name in tables or TABLES:
        out += ["", ""] + _comment(TABLES[name][1]) + table_lines(name, table_class(name))
    return "\n".join(out) + "\n"


def read_table(name: str, values: dict, source: str | Path):
    """The settings object of the table ``name`` read from ``values`` (of the file ``source``);
    a bad key or value raises an InputError naming the file and the key. ``[train]`` is read as
    ``mvm train`` reads its file (:func:`mvm.net.train_config.config_from_dict`)."""
    if name == "train":
        from mvm.net.train_config import config_from_dict

        return config_from_dict(values, str(source))
    return settings_from(table_class(name), values, str(source))


def check_settings_file(path: str | Path) -> dict:
    """Check every table of the settings file ``path`` without running anything:
    ``{table: settings object}``. An unknown table or key, a wrong type or a value out of
    range raises an InputError naming the file, the key (``table.key``) and the problem."""
    checked = {}
    for name, values in read_tables(path).items():
        try:
            checked[name] = read_table(name, values, path)
        except InputError as e:
            raise InputError(path, f"{name}.{e.field}" if e.field else name, e.problem) from None
    return checked
