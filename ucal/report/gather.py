"""What a profile and its history hold about a cell: the data of ``ucal report``, nothing drawn.

The history (``PROFILE.history/``, docs/decisions/0004) keeps the bytes each write replaced and
the SHA-256 of the bytes it left. Those are found among the history's copies (the next write's
"before", an undo's "after") and the profile itself, so that every write can be shown as what it
changed, every ``calibrate`` write by the ``[calibration]`` it left and every ``tool-frame`` write
by the ``[tool]`` it left.

``verify`` writes nothing into the profile: its picture beside it carries the facts of its run
(a PNG text chunk: when, on which cell, the profile version, the verdict and its terms). The
picture of a verify against a world file (``--sim WORLD``, ``cell.verify.WORLD.png``) is a
rehearsal on the cell that file describes, not on this one: the report shows the picture of the
last verify on this cell (the real cell, or the built-in simulated one) as the cell's, and names
the rehearsals beside it.

A profile does not hold everything a run knew: the per-measurement residuals, the full fit and
why a joint was unobservable are in the run's ``--record`` file (its end line). A record is
matched to the write its run made by the SHA-256 of the profile it started from (the write's
"before").
"""

from __future__ import annotations

import hashlib
import json
import logging
import struct
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from ucal.cell import CellProfile
from ucal.devices.record import Record, read_record
from ucal.errors import InputError, ProfileError
from ucal.kinematics.dh import RobotModel
from ucal.profile import (
    HistoryEntry,
    history_dir,
    profile_from_data,
    profile_history,
    real_path,
)
from ucal.profile.validation import DH_KEYS, parse_toml_bytes
from ucal.report.checks import CheckFacts, gather_checks
from ucal.verify.picture import verify_picture_path
from ucal.verify.procedure import PICTURE_FACTS_KEY

log = logging.getLogger(__name__)

#: History reasons (their first word) of the writes the report reads results from.
CALIBRATE = "calibrate"
TOOL_FRAME = "tool-frame"


@dataclass(frozen=True)
class Change:
    """One key a write changed: ``table.key`` (or a top-level ``key``), its plain values before
    and after (None: absent)."""

    key: str
    before: Any
    after: Any


@dataclass(frozen=True)
class Write:
    """One recorded write of the profile and what it changed (``changes`` None: the bytes it
    left are no longer kept anywhere, the profile having been edited by hand since)."""

    entry: HistoryEntry
    changes: tuple[Change, ...] | None

    @property
    def command(self) -> str:
        """The command that wrote (the reason's first word: ``calibrate``, ``tool-frame``)."""
        return self.entry.reason.split(" ", 1)[0].rstrip(":")


@dataclass(frozen=True)
class Residual:
    """One measurement's normalised residuals (dimensionless: residual / its sigma)."""

    label: str
    tilt: tuple[float, float]
    distance: float


@dataclass(frozen=True)
class Fit:
    """Fit quality of a calibration, as far as it is known (None: not held)."""

    verdict: str | None = None
    chi2_reduced: float | None = None
    dof: int | None = None
    rms_tilt_deg: float | None = None
    rms_distance_mm: float | None = None
    worst: str | None = None


@dataclass(frozen=True)
class Calibration:
    """One ``calibrate`` result as the profile holds it after its write (``write`` None: the
    profile's ``[calibration]`` without a recorded write)."""

    write: Write | None
    offsets_deg: np.ndarray  # (6,)
    std_deg: np.ndarray | None  # (6,), NaN: not determined; None: no std written
    unobservable_joints: tuple[int, ...]  # 1-based
    reasons: dict[int, str]  # 1-based joint → why it is unobservable (where known)
    fit: Fit
    method: str | None = None
    level: str | None = None
    std_block_deg: np.ndarray | None = None  # (6,) J1 relative to the block as placed
    gauge: str | None = None  # "block": J1 relative to the block only; "base": absolute too
    gauge_note: str | None = None
    approach: str | None = None  # the approach the offsets hold for ("positive", "centre")
    unidentified_tcp_mm: tuple[float, float] | None = None  # mean, max; one sigma
    date: str | None = None
    sound_speed_m_s: float | None = None
    condition_number: float | None = None
    dh: np.ndarray | None = None  # (6, 4) identified table (``--level full``), else None
    beta_deg: np.ndarray | None = None  # (6,) Hayati twists of that table
    backlash_deg: np.ndarray | None = None  # (6,), NaN: not measured; None: no key
    backlash_std_deg: np.ndarray | None = None
    drift_m_s_per_min: float | None = None  # sound speed drift during the run
    drift_std_m_s_per_min: float | None = None
    residuals: tuple[Residual, ...] = ()
    record: Path | None = None  # the --record file the residuals come from

    @property
    def applied(self) -> bool:
        return self.write is None or not self.write.entry.undone


@dataclass(frozen=True)
class ToolCalibration:
    """One ``tool-frame`` result: ``[tool]`` as its write left it (mm, deg; stds one sigma)."""

    write: Write
    position_mm: np.ndarray
    rotation_deg: np.ndarray
    position_std_mm: np.ndarray | None
    rotation_std_deg: np.ndarray | None


@dataclass(frozen=True)
class IsoFacts:
    """An ISO 9283 verify's figures as its picture carries them (mm, one sigma)."""

    cycles: int
    side_mm: float
    #: per pose: name, AP, its std, RP, its std
    poses: tuple[tuple[str, float, float, float, float], ...]


@dataclass(frozen=True)
class VerifyFacts:
    """What a verify picture carries of its run (``ucal.verify.procedure.picture_facts``)."""

    time: datetime  # UTC
    profile_sha256: str
    simulated: bool
    world: str | None  # the world file of a ``--sim WORLD`` run: a rehearsal on another cell
    controller: str | None
    points: int
    tolerance_mm: float
    worst_mm: float
    passed: bool
    marginal: bool
    measured_within_mm: float
    before_max_mm: tuple[float, ...] | None  # X, Y, Z; None: "before" was the same profile
    after_max_mm: tuple[float, ...]
    gauge_note: str
    notes: tuple[str, ...]
    #: the run was ``verify --iso9283``: its figures; None: verify's points
    iso9283: IsoFacts | None = None

    @property
    def own_cell(self) -> bool:
        """The run measured the cell the profile describes: the real cell, or the built-in
        simulated one (not a world file's)."""
        return self.world is None

    @property
    def cell_words(self) -> str:
        if self.world is not None:
            return f"the simulated cell of {self.world} (a rehearsal on another cell)"
        if self.simulated:
            return "the built-in simulated cell"
        return f"the robot at {self.controller}" if self.controller else "the real cell"


@dataclass(frozen=True)
class VerifyPicture:
    """A picture ``ucal verify`` wrote beside the profile (verify writes nothing into the
    profile or its history), the facts it carries (None: drawn by a ucal that wrote none) and
    the writes made since it was drawn."""

    path: Path
    png: bytes
    modified: datetime  # UTC: the facts' time, else the file's
    writes_since: tuple[Write, ...]
    facts: VerifyFacts | None = None

    #: A picture of this cell: its facts say so, or (without facts) the default picture.
    own_cell: bool = True


@dataclass(frozen=True)
class CellReport:
    """Everything ``ucal report`` shows of one profile."""

    path: Path
    profile: CellProfile
    nominal_model: RobotModel  # [robot] dh or the shipped table: what [calibration] dh replaces
    identified_dh: bool  # the profile's kinematics use [calibration] dh
    history_dir: Path
    writes: tuple[Write, ...]
    calibrations: tuple[Calibration, ...]
    tools: tuple[ToolCalibration, ...]
    verify: VerifyPicture | None  # the last verify on this cell (module docstring)
    generated: datetime
    profile_sha256: str
    notes: tuple[str, ...] = field(default=())
    #: Verify pictures of other cells (``--sim WORLD`` rehearsals), newest first.
    rehearsals: tuple[VerifyPicture, ...] = ()
    #: Every ``ucal check`` of the cell, oldest first (``ucal.report.checks``).
    checks: tuple[CheckFacts, ...] = ()

    @property
    def current_calibration(self) -> Calibration | None:
        """The newest calibration still applied (None: never calibrated)."""
        applied = [c for c in self.calibrations if c.applied]
        return applied[-1] if applied else None


# ---------------------------------------------------------------------------------------------
# gathering


def gather_report(
    path: str | Path, records: Sequence[str | Path] = (), now: datetime | None = None
) -> CellReport:
    """Read the profile at ``path``, its history and the ``records`` of its calibrate runs.

    Raises :class:`ProfileError` (exit 2, naming the file) for a missing or invalid profile or
    history index, :class:`InputError` for a record that cannot be read or that matches no
    write of this profile.
    """
    p = Path(path)
    try:
        current = p.read_bytes()
    except OSError as e:
        raise ProfileError(p, None, f"cannot read: {e.strerror or e}") from None
    doc = parse_toml_bytes(current, p)
    profile = profile_from_data(doc, p)
    text = doc.unwrap()
    entries = profile_history(p)
    states = _states(p, current)
    writes = tuple(_write(e, states, p) for e in entries)

    calibrations: list[Calibration] = []
    tools: list[ToolCalibration] = []
    notes: list[str] = []
    for w in writes:
        after = _plain(states.get(w.entry.after_sha256), p)
        if w.command == CALIBRATE and after is not None:
            calibrations.append(_calibration(w, after.get("calibration")))
        elif w.command == TOOL_FRAME and after is not None:
            tools.append(_tool(w, after.get("tool")))
        elif w.command in (CALIBRATE, TOOL_FRAME):
            notes.append(
                f"write {w.entry.id} ({w.command}, {w.entry.time}): the profile it left is kept "
                "nowhere (edited by hand since): its values are not shown"
            )
    cal_now = text.get("calibration")
    if not calibrations and isinstance(cal_now, Mapping):
        # offsets written by hand (or by a ucal that kept no history); a new profile's zeros
        # without a std are "not calibrated"
        by_hand = _calibration(None, cal_now)
        if by_hand.std_deg is not None or np.any(by_hand.offsets_deg != 0.0):
            calibrations.append(by_hand)
    calibrations = _attach_records(calibrations, [read_record(r) for r in records], p)
    pictures = _verify_pictures(p, writes)
    own = [v for v in pictures if v.own_cell]

    return CellReport(
        path=p,
        profile=profile,
        nominal_model=_nominal_model(text, p),
        identified_dh=isinstance(cal_now, Mapping) and "dh" in cal_now,
        history_dir=history_dir(p),
        writes=writes,
        calibrations=tuple(calibrations),
        tools=tuple(tools),
        verify=own[0] if own else None,
        generated=now or datetime.now(UTC),
        profile_sha256=_sha(current),
        notes=tuple(notes),
        rehearsals=tuple(v for v in pictures if not v.own_cell),
        checks=gather_checks(p),
    )


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _states(path: Path, current: bytes) -> dict[str, bytes]:
    """Every profile version the history keeps, and the profile itself, by SHA-256."""
    states: dict[str, bytes] = {}
    hdir = history_dir(path)
    if hdir.is_dir():
        for f in sorted(hdir.glob("*.toml")):
            try:
                data = f.read_bytes()
            except OSError as e:
                log.warning("%s: cannot read (%s): skipped", f, e.strerror or e)
                continue
            states[_sha(data)] = data
    states[_sha(current)] = current
    return states


def _plain(data: bytes | None, path: Path) -> dict[str, Any] | None:
    """A profile version as plain data (None: not kept, or not TOML any more)."""
    if data is None:
        return None
    try:
        plain: dict[str, Any] = parse_toml_bytes(data, path).unwrap()
    except ProfileError as e:
        log.warning("%s", e)
        return None
    return plain


def _write(entry: HistoryEntry, states: Mapping[str, bytes], path: Path) -> Write:
    before = _plain(states.get(entry.before_sha256), path)
    after = _plain(states.get(entry.after_sha256), path)
    if before is None or after is None:
        return Write(entry, None)
    return Write(entry, tuple(diff(before, after)))


def diff(before: Mapping[str, Any], after: Mapping[str, Any]) -> Iterable[Change]:
    """The keys whose values differ between two profile versions (plain data), in the later
    version's order, then the removed ones."""

    def flat(doc: Mapping[str, Any]) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for name, value in doc.items():
            if isinstance(value, Mapping):
                out.update({f"{name}.{k}": v for k, v in value.items()})
            else:
                out[name] = value
        return out

    old, new = flat(before), flat(after)
    for key, value in new.items():
        if old.get(key) != value:
            yield Change(key, old.get(key), value)
    for key, value in old.items():
        if key not in new:
            yield Change(key, value, None)


# ---------------------------------------------------------------------------------------------
# reading results from a profile version (plain data; a version ucal no longer validates still
# shows what it holds)


def _vector(table: Mapping[str, Any], key: str, n: int, missing_below: float | None = None) -> Any:
    """``table[key]`` as n floats (None: absent or not n numbers); entries below
    ``missing_below`` (the profile's -1: not determined) become NaN."""
    raw = table.get(key)
    if not isinstance(raw, list) or len(raw) != n:
        return None
    try:
        v = np.array([float(x) for x in raw])
    except (TypeError, ValueError):
        return None
    if missing_below is not None:
        v = np.where(v < missing_below, np.nan, v)
    return v


def _number(table: Mapping[str, Any], key: str) -> float | None:
    raw = table.get(key)
    if isinstance(raw, bool) or not isinstance(raw, (int, float)):
        return None
    return float(raw)


def _pair(table: Mapping[str, Any], key: str) -> tuple[float, float] | None:
    v = _vector(table, key, 2)
    return None if v is None else (float(v[0]), float(v[1]))


def _text(table: Mapping[str, Any], key: str) -> str | None:
    raw = table.get(key)
    return None if raw is None else str(raw)


def _joints(raw: Any) -> tuple[int, ...]:
    if not isinstance(raw, list):
        return ()
    return tuple(int(j) for j in raw if isinstance(j, int) and not isinstance(j, bool))


def _reasons(raw: Any) -> dict[int, str]:
    """``{"1": "why", ...}`` (a record's ``unobservable_reasons``, or the same in a profile)."""
    if not isinstance(raw, Mapping):
        return {}
    out = {}
    for k, v in raw.items():
        try:
            out[int(k)] = str(v)
        except ValueError:
            continue
    return out


def _calibration(write: Write | None, table: Any) -> Calibration:
    t: Mapping[str, Any] = table if isinstance(table, Mapping) else {}
    offsets = _vector(t, "joint_offsets_deg", 6)
    dh, beta = None, None
    rows = t.get("dh")
    if isinstance(rows, list) and len(rows) == 6 and all(isinstance(r, Mapping) for r in rows):
        try:
            dh = np.array([[float(r[k]) for k in DH_KEYS] for r in rows])
            beta = np.array([float(r.get("beta_deg", 0.0)) for r in rows])
        except (KeyError, TypeError, ValueError):
            dh, beta = None, None
    dof = t.get("dof")
    return Calibration(
        write=write,
        offsets_deg=np.zeros(6) if offsets is None else offsets,
        std_deg=_vector(t, "std_deg", 6, missing_below=0.0),
        unobservable_joints=_joints(t.get("unobservable_joints")),
        reasons=_reasons(t.get("unobservable_reasons")),
        fit=Fit(
            verdict=_text(t, "fit_verdict"),
            chi2_reduced=_number(t, "chi2_reduced"),
            dof=dof if isinstance(dof, int) and not isinstance(dof, bool) else None,
            rms_tilt_deg=_number(t, "rms_tilt_deg"),
            rms_distance_mm=_number(t, "rms_distance_mm"),
            worst=_text(t, "worst"),
        ),
        method=_text(t, "method"),
        level=_text(t, "level"),
        std_block_deg=_vector(t, "std_block_deg", 6, missing_below=0.0),
        gauge=_text(t, "gauge"),
        gauge_note=_text(t, "gauge_note"),
        approach=_text(t, "approach"),
        unidentified_tcp_mm=_pair(t, "unidentified_tcp_mm"),
        date=_text(t, "date"),
        sound_speed_m_s=_number(t, "sound_speed_m_s"),
        condition_number=_number(t, "condition_number"),
        dh=dh,
        beta_deg=beta,
        backlash_deg=_vector(t, "backlash_deg", 6, missing_below=0.0),
        backlash_std_deg=_vector(t, "backlash_std_deg", 6, missing_below=0.0),
        drift_m_s_per_min=_number(t, "sound_speed_drift_m_s_per_min"),
        drift_std_m_s_per_min=_number(t, "sound_speed_drift_m_s_per_min_std"),
    )


def _tool(write: Write, table: Any) -> ToolCalibration:
    t: Mapping[str, Any] = table if isinstance(table, Mapping) else {}
    pos, rot = _vector(t, "position_mm", 3), _vector(t, "rotation_deg", 3)
    return ToolCalibration(
        write=write,
        position_mm=np.full(3, np.nan) if pos is None else pos,
        rotation_deg=np.full(3, np.nan) if rot is None else rot,
        position_std_mm=_vector(t, "position_std_mm", 3),
        rotation_std_deg=_vector(t, "rotation_std_deg", 3),
    )


def _nominal_model(data: Mapping[str, Any], path: Path) -> RobotModel:
    """The model of ``[robot]`` alone: the shipped or ``[robot] dh`` table, which an identified
    ``[calibration] dh`` replaces (with its stds, ``dh_std``)."""
    cal = data.get("calibration")
    if not isinstance(cal, Mapping) or "dh" not in cal:
        return profile_from_data(data, path).model
    without = dict(data)
    without["calibration"] = {k: v for k, v in cal.items() if k not in ("dh", "dh_std")}
    return profile_from_data(without, path).model


# ---------------------------------------------------------------------------------------------
# records and the verify picture


def _attach_records(
    calibrations: list[Calibration], records: Sequence[Record], path: Path
) -> list[Calibration]:
    """Each record's residuals, fit and reasons added to the calibration its run wrote."""
    out = list(calibrations)
    for rec in records:
        command = str(rec.header.get("command", ""))
        if command != CALIBRATE:
            raise InputError(
                f"{rec.path}: a record of {command or 'an unknown command'}; the report reads "
                f"the records of {CALIBRATE} runs"
            )
        result = rec.result
        if result is None or not result.get("written"):
            raise InputError(
                f"{rec.path}: its run wrote nothing into a profile "
                + ("(it did not finish)" if result is None else "(not written)")
            )
        sha = rec.header.get("profile_sha256")
        candidates = [
            i
            for i, c in enumerate(out)
            if c.write is not None and c.write.entry.before_sha256 == sha
        ]
        if not candidates:
            raise InputError(
                f"{rec.path}: its run (started {rec.header.get('started_utc', '?')}) made no "
                f"write in the history of {real_path(path)}"
            )
        recorded = np.asarray(result.get("joint_offsets_deg", []), float)
        # a run repeated from the same profile (after an undo): the write with its offsets
        i = min(
            reversed(candidates),
            key=lambda i: (
                float(np.max(np.abs(out[i].offsets_deg - recorded)))
                if recorded.shape == (6,)
                else 0.0
            ),
        )
        out[i] = _with_record(out[i], rec, result)
    return out


def _with_record(cal: Calibration, rec: Record, result: Mapping[str, Any]) -> Calibration:
    residuals = tuple(
        Residual(str(r["label"]), (float(r["tilt"][0]), float(r["tilt"][1])), float(r["distance"]))
        for r in result.get("residuals", [])
    )
    f = result.get("fit") or {}
    fit = Fit(
        verdict=f.get("verdict", cal.fit.verdict),
        chi2_reduced=f.get("chi2_reduced", cal.fit.chi2_reduced),
        dof=f.get("dof", cal.fit.dof),
        rms_tilt_deg=f.get("rms_tilt_deg", cal.fit.rms_tilt_deg),
        rms_distance_mm=f.get("rms_distance_mm", cal.fit.rms_distance_mm),
        worst=f.get("worst", cal.fit.worst),
    )
    reasons = {**_reasons(result.get("unobservable_reasons")), **cal.reasons}
    return replace(cal, residuals=residuals, fit=fit, reasons=reasons, record=rec.path)


def _verify_pictures(path: Path, writes: Sequence[Write]) -> list[VerifyPicture]:
    """Every picture ``ucal verify`` wrote by default beside the profile (``cell.verify.png``,
    ``cell.verify.WORLD.png``), newest first."""
    own = verify_picture_path(path)
    found = {own, *own.parent.glob(f"{glob_escape(path.stem)}.verify.*.png")}
    pictures = [v for v in (_verify_picture(f, own, writes) for f in found) if v is not None]
    return sorted(pictures, key=lambda v: v.modified, reverse=True)


def glob_escape(text: str) -> str:
    """``text`` with glob's special characters matched literally."""
    return "".join(f"[{c}]" if c in "*?[" else c for c in text)


def _verify_picture(picture: Path, default: Path, writes: Sequence[Write]) -> VerifyPicture | None:
    try:
        png = picture.read_bytes()
        modified = datetime.fromtimestamp(picture.stat().st_mtime, UTC)
    except OSError:
        return None
    facts = _facts(png_text(png).get(PICTURE_FACTS_KEY), picture)
    if facts is not None:
        modified = facts.time
    since = tuple(
        w for w in writes if datetime.fromisoformat(w.entry.time) > modified.replace(microsecond=0)
    )
    own = facts.own_cell if facts is not None else picture == default
    return VerifyPicture(picture, png, modified, since, facts, own)


def png_text(png: bytes) -> dict[str, str]:
    """The ``tEXt`` chunks of a PNG file (keyword → text; latin-1); {} when it is not one."""
    if png[:8] != b"\x89PNG\r\n\x1a\n":
        return {}
    out: dict[str, str] = {}
    at = 8
    while at + 8 <= len(png):
        # uint32 big-endian: data length; 4 bytes: chunk type; data; uint32: CRC
        (length,) = struct.unpack(">I", png[at : at + 4])
        kind = png[at + 4 : at + 8]
        data = png[at + 8 : at + 8 + length]
        if kind == b"tEXt" and b"\0" in data:
            key, _, text = data.partition(b"\0")
            out[key.decode("latin-1")] = text.decode("latin-1")
        elif kind == b"IEND":
            break
        at += 12 + length
    return out


def _facts(text: str | None, picture: Path) -> VerifyFacts | None:
    """The facts a verify picture carries (None: none, or not readable: said in the log)."""
    if text is None:
        return None
    try:
        d = json.loads(text)
        cell = d["cell"]
        before = d.get("before_max_mm")
        return VerifyFacts(
            time=datetime.fromisoformat(d["time_utc"]),
            profile_sha256=str(d["profile_sha256"]),
            simulated=bool(cell["simulated"]),
            world=None if cell.get("world") is None else str(cell["world"]),
            controller=None if cell.get("controller") is None else str(cell["controller"]),
            points=int(d["points"]),
            tolerance_mm=float(d["tolerance_mm"]),
            worst_mm=float(d["worst_mm"]),
            passed=bool(d["passed"]),
            marginal=bool(d["marginal"]),
            measured_within_mm=float(d["measured_within_mm"]),
            before_max_mm=None if before is None else tuple(_finite(v) for v in before),
            after_max_mm=tuple(_finite(v) for v in d["after_max_mm"]),
            gauge_note=str(d.get("gauge_note", "")),
            notes=tuple(str(n) for n in d.get("notes", [])),
            iso9283=_iso_facts(d.get("iso9283")),
        )
    except (ValueError, KeyError, TypeError) as e:
        log.warning("%s: its verify facts cannot be read (%s): shown without them", picture, e)
        return None


def _iso_facts(d: Any) -> IsoFacts | None:
    """An ISO 9283 run's figures from its picture's facts (None: verify's points)."""
    if d is None:
        return None
    poses = tuple(
        (
            str(p["name"]),
            _finite(p["ap_mm"]),
            _finite(p["ap_std_mm"]),
            _finite(p["rp_mm"]),
            _finite(p["rp_std_mm"]),
        )
        for p in d["poses"]
    )
    return IsoFacts(int(d["cycles"]), float(d["side_mm"]), poses)


def _finite(v: Any) -> float:
    return float("nan") if v is None else float(v)
