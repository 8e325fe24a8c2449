"""The posture whose gravity load a calibration's offsets hold (``ucal.model.load``)."""

from __future__ import annotations

from typing import Any


def load_posture(chosen: Any, sound: Any) -> list[float] | None:
    """The readings whose gravity load the offsets of ``chosen`` hold (its fit's, else the
    fit of ``sound``'s: ``ucal.model.load``); None where nothing weighs."""
    cell = chosen.cell_fit if chosen.cell_fit is not None else sound.cell_fit
    if cell is None or cell.load_posture_deg is None:
        return None
    return [float(v) for v in cell.load_posture_deg]
