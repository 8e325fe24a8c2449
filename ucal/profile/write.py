"""Write results into a profile, keeping its comments and key order, and create new profiles.

The new text is validated as a profile before anything touches the disk; the replaced bytes
go to the profile's history (:mod:`ucal.profile.history`), so every write can be undone.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import tomlkit
from tomlkit.items import Array, InlineTable, Table

from ucal.errors import ProfileError
from ucal.kinematics.dh import RobotModel
from ucal.profile.disk import atomic_write, real_path
from ucal.profile.history import HistoryEntry, _replace_with_history
from ucal.profile.lock import profile_lock
from ucal.profile.read import profile_from_data
from ucal.profile.template import default_profile_text
from ucal.profile.validation import parse_toml_bytes

log = logging.getLogger(__name__)


def to_plain(value: Any) -> Any:
    """numpy arrays/scalars and tuples → plain lists, floats, ints (recursively)."""
    if isinstance(value, np.ndarray):
        return [to_plain(v) for v in value.tolist()]
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    if isinstance(value, (list, tuple)):
        return [to_plain(v) for v in value]
    if isinstance(value, Mapping):
        return {str(k): to_plain(v) for k, v in value.items()}
    return value


def _is_multiline(item: Any) -> bool:
    return isinstance(item, Array) and "\n" in item.as_string()


def _toml_value(value: Any, old: Any) -> Any:
    """A plain value → tomlkit item; arrays keep the old value's one-line/multiline layout;
    a list of tables becomes a multiline array of inline tables (as the ``dh`` table)."""
    if isinstance(value, list):
        arr = tomlkit.array()
        for v in value:
            if isinstance(v, Mapping):
                it = tomlkit.inline_table()
                it.update(v)
                arr.append(it)
            else:
                arr.append(v)
        if _is_multiline(old) or (
            old is None and any(isinstance(v, (Mapping, list)) for v in value)
        ):
            arr.multiline(True)
        return arr
    if isinstance(value, Mapping) and isinstance(old, InlineTable):
        it = tomlkit.inline_table()
        it.update(value)
        return it
    return tomlkit.item(value)


def _set_key(table: Any, key: str, value: Any) -> None:
    """Set ``key`` in a tomlkit table: in place if present (its comment kept), else after the
    table's last key (not after the comments that introduce the next table)."""
    if value is None:
        if key in table:
            del table[key]
        return
    old = table.get(key) if key in table else None
    item = _toml_value(value, old)
    if old is not None:
        table[key] = item
        return
    keys = list(table)
    # tomlkit appends after the table's trailing comments, i.e. below the comment that
    # introduces the next table; inserting at the body position after the last key avoids
    # that (Container._insert_after before tomlkit 0.15, _insert_at since: no public
    # equivalent). If a tomlkit release drops both, the key is appended (still valid TOML).
    container = table.value if isinstance(table, Table) and keys else None
    if container is not None and hasattr(container, "_insert_after"):
        container._insert_after(keys[-1], key, item)
    elif container is not None and hasattr(container, "_insert_at"):
        last = max(
            i
            for i, (k, _) in enumerate(container.body)
            if k is not None and getattr(k, "key", None) == keys[-1]
        )
        if last + 1 < len(container.body):  # a comment or a blank line follows it
            container._insert_at(last + 1, key, item)
        else:
            table[key] = item
    else:
        table[key] = item


def render_update(text: str, updates: Mapping[str, Mapping[str, Any]]) -> str:
    """Apply ``updates`` (table → key → value; ``None`` deletes the key) to TOML ``text``,
    keeping comments and key order; missing tables are appended."""
    doc = tomlkit.parse(text)
    for tname, keys in updates.items():
        if not isinstance(keys, Mapping):
            doc[tname] = tomlkit.item(to_plain(keys))
            continue
        if tname not in doc:
            doc.add(tname, tomlkit.table())
        table = doc[tname]
        for key, value in keys.items():
            _set_key(table, key, to_plain(value))
    return tomlkit.dumps(doc)


def write_profile(
    path: str | Path, updates: Mapping[str, Mapping[str, Any]], reason: str
) -> HistoryEntry | None:
    """Write ``updates`` (e.g. ``{"calibration": {"joint_offsets_deg": offsets}}``) into the
    profile at ``path``, atomically, keeping comments and key order, and record the replaced
    bytes in the history with ``reason`` (e.g. ``"calibrate"``).

    The result is validated as a profile first. Any failure raises :class:`ProfileError`
    (exit 2) and leaves the profile byte-for-byte unchanged. A symlinked profile is written
    through the link (the link stays a link; the history sits beside the real file). Returns
    the history entry of the write (None: nothing changed, nothing written).
    """
    p = real_path(path)
    try:
        before = p.read_bytes()
    except OSError as e:
        raise ProfileError(p, None, f"cannot read: {e.strerror or e}") from None
    text = parse_toml_bytes(before, p).as_string()
    after = render_update(text, updates).encode("utf-8")
    profile_from_data(parse_toml_bytes(after, p), p)
    if after == before:
        log.info("%s: nothing to change", p)
        return None
    return _replace_with_history(p, after, reason, before)


def create_profile(
    path: str | Path, model: str | RobotModel, force: bool = False, dh_source: str = ""
) -> Path:
    """Write a new profile for ``model`` (a shipped name, or another arm's model whose table
    comes from ``dh_source``) at ``path``; refuse (exit 2) if it exists unless ``force`` (the
    replaced file then goes to the history, so it can be undone)."""
    p = Path(path)
    text = default_profile_text(model, dh_source)
    model = model.name if isinstance(model, RobotModel) else model
    profile_from_data(tomlkit.parse(text), p)  # the template must always validate
    if p.is_symlink():  # write through the link: it stays a link
        p = real_path(p)
    if p.exists():
        if not force:
            raise ProfileError(
                p,
                None,
                "already exists (use --force to replace it; the old file is kept in the history)",
            )
        # A run that holds the profile (calibrate, tool-frame) writes into it at its end: a
        # new profile under it would receive results measured on another cell description.
        with profile_lock(p, f"ucal profile init {model} {p} --force"):
            _replace_with_history(p, text.encode("utf-8"), f"init {model} --force")
    else:
        try:
            p.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise ProfileError(p, None, f"cannot create directory: {e.strerror or e}") from None
        atomic_write(p, text.encode("utf-8"))
    return p
