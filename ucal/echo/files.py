"""A-scans and reference echoes in CSV files: ``t_ns``, then one column per record.

The format of ``ucal echo`` (SPEC.md): the first column the time of each sample (ns, uniform
sampling), one column per A-scan; a reference echo file holds one column, its arrival at
``t_ns = 0``. The profile's ``[pulser] reference_echo`` names such a file. A reference is
read with its offset removed and its own noise measured (``reference_from_samples``).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from ucal.echo.ascan import ReferenceEcho, echo_noise_rms
from ucal.errors import InputError

#: Name of the time column (ns) that starts every A-scan or reference file.
TIME_COLUMN = "t_ns"
#: Largest departure of a sample time from the uniform grid, as a fraction of the interval.
UNIFORM_TOLERANCE = 1e-3
#: Sample intervals (ns) a digitiser of ultrasonic echoes records at: 20 GS/s to 1 MS/s. An
#: interval outside is times in another unit (s or µs where ns are meant), refused by name.
DT_RANGE_NS = (0.05, 1000.0)
#: Largest sample magnitude taken (volts, or a digitiser's codes: 16 bits are 65,536): larger
#: is not a reading, and its squares would overflow the estimator's sums.
MAX_SAMPLE = 1e9


def read_columns(path: Path) -> tuple[float, float, list[str], np.ndarray]:
    """Read ``t_ns,<name>,...`` rows → ``(t0_ns, dt_ns, names, columns (k, n))``.

    Blank lines and lines starting with ``#`` are skipped; the first line is the header. Raises
    ``InputError`` (exit 2) naming the file: unreadable, no header or no column after
    ``t_ns``, a row that is not numbers, fewer than 8 samples, ``t_ns`` not increasing
    uniformly (within ``UNIFORM_TOLERANCE`` of the interval) or at an interval outside
    ``DT_RANGE_NS``, or a sample beyond ``MAX_SAMPLE``.
    """
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read: {getattr(e, 'strerror', None) or e}") from None
    lines = [
        (i, fields)
        for i, fields in enumerate(csv.reader(text.splitlines()), 1)
        if fields and "".join(fields).strip() and not fields[0].lstrip().startswith("#")
    ]
    if not lines:
        raise InputError(f"{path}: empty: expected a header {TIME_COLUMN},<A-scan>,...")
    header = [h.strip() for h in lines[0][1]]
    if header[0] != TIME_COLUMN:
        raise InputError(f"{path}: the first column must be {TIME_COLUMN}, got {header[0]!r}")
    if len(header) < 2:
        raise InputError(f"{path}: no A-scan columns after {TIME_COLUMN}")
    rows = []
    for lineno, fields in lines[1:]:
        try:
            values = [float(f) for f in fields]
        except ValueError:
            raise InputError(f"{path}: row {lineno}: not numbers: {','.join(fields)!r}") from None
        if len(values) != len(header) or not all(math.isfinite(v) for v in values):
            raise InputError(
                f"{path}: row {lineno}: expected {len(header)} finite numbers "
                f"({','.join(header)}), got {len(values)} value(s)"
            )
        rows.append(values)
    if len(rows) < 8:
        raise InputError(f"{path}: {len(rows)} sample(s); an A-scan needs at least 8")
    table = np.array(rows)
    t_ns = table[:, 0]
    dt_ns = (t_ns[-1] - t_ns[0]) / (t_ns.size - 1)
    if not dt_ns > 0.0:
        raise InputError(f"{path}: {TIME_COLUMN} must increase")
    off = np.abs(t_ns - (t_ns[0] + dt_ns * np.arange(t_ns.size))) / dt_ns
    if off.max() > UNIFORM_TOLERANCE:
        k = int(np.argmax(off))
        raise InputError(
            f"{path}: {TIME_COLUMN} is not uniformly sampled: row {lines[k + 1][0]} "
            f"({t_ns[k]:g} ns) is {off[k]:.3g} of the interval ({dt_ns:g} ns) off the grid"
        )
    lo_ns, hi_ns = DT_RANGE_NS
    if not lo_ns <= dt_ns <= hi_ns:
        raise InputError(
            f"{path}: {TIME_COLUMN} advances {dt_ns:.3g} ns a sample, outside the "
            f"{lo_ns:g}–{hi_ns:g} ns of a digitiser (20 GS/s to 1 MS/s): {TIME_COLUMN} is in "
            "nanoseconds (times in seconds or µs?)"
        )
    big = np.abs(table[:, 1:]) > MAX_SAMPLE
    if big.any():
        k, j = (int(i[0]) for i in np.nonzero(big))
        raise InputError(
            f"{path}: row {lines[k + 1][0]}, column {header[j + 1]!r}: sample "
            f"{table[k, j + 1]:.3g} is beyond ±{MAX_SAMPLE:.0e}: not a digitiser's reading "
            "(volts or codes)"
        )
    return float(t_ns[0]), float(dt_ns), header[1:], table[:, 1:].T


def read_reference(path: Path) -> ReferenceEcho:
    """Read a reference echo: ``t_ns`` and one column, its arrival at ``t_ns = 0``."""
    t0_ns, dt_ns, names, columns = read_columns(path)
    if len(names) != 1:
        raise InputError(
            f"{path}: a reference holds one echo: expected {TIME_COLUMN} and one column, "
            f"got {len(names)} columns after {TIME_COLUMN}"
        )
    t_last = t0_ns + (columns.shape[1] - 1) * dt_ns
    if not t0_ns <= 0.0 <= t_last:
        raise InputError(
            f"{path}: the echo's arrival, {TIME_COLUMN} = 0, is outside its "
            f"{TIME_COLUMN} range {t0_ns:g}…{t_last:g} ns"
        )
    try:
        return reference_from_samples(t0_ns, dt_ns, columns[0])
    except ValueError as e:
        raise InputError(f"{path}: {e}") from None


def reference_from_samples(t0_ns: float, dt_ns: float, samples: np.ndarray) -> ReferenceEcho:
    """A reference echo as a file gives it: its offset removed (the mean: an echo has no DC),
    its noise measured outside the echo (``echo_noise_rms``: a capture written as it came
    keeps its noise, which the bound, the template and the std must know)."""
    x = np.asarray(samples, float)
    x = x - float(np.mean(x))
    return ReferenceEcho(t0_ns, dt_ns, x, echo_noise_rms(x))
