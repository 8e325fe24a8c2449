"""What the report states of the cell, each quantity judged once: the page's verdict and its
tables both read these, so that no sentence of the page says what a table of it does not.

A quantity is *determined* when its one sigma is within its tolerance, *not determined* when
it exceeds it (said with what would determine it: never "ok"), *not measured* when no run
measured it. The tolerances are the ones the commands judge by: a joint offset 0.02°
(``ucal.model.priors.MAX_STD_DEG``); the tool across the beam 0.05 mm and its beam
direction 0.01° (``ucal.toolframe.fit``); the sound speed's drift the profile's declared
``[water] drift_std_c_per_min``. A verify is judged as it judged itself (its picture's facts):
a pass within what verify measures to of its tolerance is marginal, the pass not determined.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ucal.acoustics import sound_speed_slope_m_s_per_c
from ucal.model.priors import MAX_STD_DEG
from ucal.report.gather import Calibration, CellReport, VerifyFacts, VerifyPicture
from ucal.toolframe.fit import TOLERANCE_BEAM_DEG, TOLERANCE_POSITION_MM

DETERMINED = "determined"
NOT_DETERMINED = "not determined"
NOT_MEASURED = "not measured"

#: Tolerance of a joint's offset and of its lost motion (deg, one sigma).
JOINT_TOLERANCE_DEG = MAX_STD_DEG


@dataclass(frozen=True)
class Quantity:
    """One quantity the page states: its value and one sigma in words with their unit, the
    tolerance its sigma is judged against, its state and why (what would determine it)."""

    name: str
    value: str
    std: str
    tolerance: str
    state: str
    why: str = ""

    @property
    def determined(self) -> bool:
        return self.state == DETERMINED


def deg(v: float, digits: int = 4) -> str:
    return f"{round(float(v), digits) + 0.0:.{digits}f}°"


def mm(v: float, digits: int = 3) -> str:
    return f"{round(float(v), digits) + 0.0:.{digits}f} mm"


def _judge(std: float, tolerance: float) -> str:
    return DETERMINED if math.isfinite(std) and std <= tolerance else NOT_DETERMINED


# ---------------------------------------------------------------------------------------------
# the calibration


def joint_quantities(cal: Calibration) -> list[Quantity]:
    """Each joint's offset; J1 in the block gauge twice (relative to the block, and in the
    robot's base frame) when the calibration says it is relative to the block only."""
    out = []
    tol = deg(JOINT_TOLERANCE_DEG, 2)
    for j in range(6):
        name = f"J{j + 1} offset"
        value = deg(cal.offsets_deg[j])
        std = np.nan if cal.std_deg is None else float(cal.std_deg[j])
        if j + 1 in cal.unobservable_joints:
            why = cal.reasons.get(j + 1) or (
                "reason not recorded in the profile (the run's record has it)"
            )
            out.append(
                Quantity(
                    name,
                    value + " (kept from the profile)",
                    "—",
                    tol,
                    NOT_DETERMINED,
                    f"{why}; a measurement that moves the beam when J{j + 1} turns would "
                    "determine it",
                )
            )
            continue
        if cal.std_deg is None:
            out.append(
                Quantity(
                    name,
                    value,
                    "not written",
                    tol,
                    NOT_DETERMINED,
                    "the profile holds no std for it: `ucal calibrate` measures it",
                )
            )
            continue
        block = None if cal.std_block_deg is None else float(cal.std_block_deg[j])
        if j == 0 and cal.gauge == "block" and block is not None and math.isfinite(block):
            out.append(
                Quantity(
                    "J1 offset, relative to the block",
                    value,
                    deg(block),
                    tol,
                    _judge(block, JOINT_TOLERANCE_DEG),
                    "J1 and the block's yaw are one rotation: measured against the block as placed",
                )
            )
            state = _judge(std, JOINT_TOLERANCE_DEG)
            out.append(
                Quantity(
                    "J1 offset, in the robot's base frame",
                    value,
                    deg(std),
                    tol,
                    state,
                    ""
                    if state == DETERMINED
                    else "its σ is the block's yaw as placed; a doweled, levelled block "
                    f"([sample] rotation_std_deg ≤ {0.5 * JOINT_TOLERANCE_DEG:g}) would "
                    "determine it",
                )
            )
            continue
        state = _judge(std, JOINT_TOLERANCE_DEG)
        out.append(
            Quantity(
                name,
                value,
                deg(std),
                tol,
                state,
                "" if state == DETERMINED else "more measurements of this joint would",
            )
        )
    return out


def lost_motion_quantities(cal: Calibration | None) -> list[Quantity]:
    """Each joint's lost motion (backlash): not measured unless ``--lost-motion`` (or the full
    level's postures from above) measured it."""
    tol = deg(JOINT_TOLERANCE_DEG, 2)
    how = (
        "every posture was approached from below: `ucal calibrate --lost-motion` measures it "
        "(the offsets hold for postures reached from below)"
    )
    out = []
    for j in range(6):
        name = f"J{j + 1} lost motion"
        value = None if cal is None or cal.backlash_deg is None else float(cal.backlash_deg[j])
        if value is None or not math.isfinite(value):
            out.append(Quantity(name, "—", "—", tol, NOT_MEASURED, how))
            continue
        stds = None if cal is None else cal.backlash_std_deg
        std = np.nan if stds is None else float(stds[j])
        state = _judge(std, JOINT_TOLERANCE_DEG)
        out.append(
            Quantity(
                name,
                deg(value),
                "—" if not math.isfinite(std) else deg(std),
                tol,
                state,
                "" if state == DETERMINED else "more postures read from above would",
            )
        )
    return out


def lost_motion_words(cal: Calibration | None) -> str:
    """Lost motion in one phrase, from the same judgement as its table."""
    rows = lost_motion_quantities(cal)
    measured = [q.name.split()[0] for q in rows if q.state != NOT_MEASURED]
    if not measured:
        return "not measured on any joint"
    if len(measured) == len(rows):
        return "measured on every joint"
    return f"measured on {', '.join(measured)}; not measured on the others"


def drift_quantity(r: CellReport) -> Quantity | None:
    """The sound speed's drift during the last calibration (m/s per minute)."""
    cal = r.current_calibration
    if cal is None or cal.drift_m_s_per_min is None:
        return None
    p = r.profile
    tol = p.drift_std_c_per_min * sound_speed_slope_m_s_per_c(p.water_temperature_c)
    std = np.nan if cal.drift_std_m_s_per_min is None else cal.drift_std_m_s_per_min
    state = _judge(std, tol)
    return Quantity(
        "sound speed drift during the calibration",
        f"{cal.drift_m_s_per_min:+.4f} m/s per min",
        f"{std:.4f} m/s per min",
        f"{tol:.3f} m/s per min ([water] drift_std_c_per_min)",
        state,
        "" if state == DETERMINED else "a longer run, or a logging thermometer, would",
    )


def dh_quantity(r: CellReport) -> Quantity:
    """The DH table: identified by the full level, or held at its tolerance."""
    cal = r.current_calibration
    budget = None if cal is None else cal.unidentified_tcp_mm
    allows = "" if budget is None else f"up to {mm(budget[1])} at the tool centre"
    if r.identified_dh:
        return Quantity(
            "DH table",
            "identified (calibrate --level full)",
            allows or "—",
            "—",
            DETERMINED,
            "" if not allows else "what is left unidentified allows " + allows,
        )
    return Quantity(
        "DH table",
        "not identified: the [robot] table",
        "—",
        "—",
        NOT_DETERMINED,
        "held at its tolerance"
        + (f", which allows {allows} (one sigma)" if allows else "")
        + "; `ucal calibrate --level full` would determine it",
    )


# ---------------------------------------------------------------------------------------------
# the tool


def tool_quantities(r: CellReport) -> list[Quantity]:
    """The tool frame as the profile holds it: across the beam, along it, its direction and
    the rotation about it."""
    p = r.profile
    pos, rot = p.tool_position_mm, p.tool_rotation_deg
    pstd, rstd = p.tool_position_std_mm, p.tool_rotation_std_deg
    drawn = "" if r.tools else " (from the drawing: no tool-frame write)"
    across = float(np.max(pstd[:2]))
    across_state = _judge(across, TOLERANCE_POSITION_MM)
    direction = float(np.max(rstd[:2]))
    direction_state = _judge(direction, TOLERANCE_BEAM_DEG)
    along_state = _judge(float(pstd[2]), TOLERANCE_POSITION_MM)
    about_state = _judge(float(rstd[2]), TOLERANCE_BEAM_DEG)
    run = "`ucal tool-frame` would determine it"
    return [
        Quantity(
            "tool centre across the beam (x, y)",
            f"{pos[0]:.4f}, {pos[1]:.4f} mm{drawn}",
            f"{pstd[0]:.4f}, {pstd[1]:.4f} mm",
            mm(TOLERANCE_POSITION_MM, 2),
            across_state,
            "" if across_state == DETERMINED else run,
        ),
        Quantity(
            "tool centre along the beam (z)",
            f"{pos[2]:.4f} mm{drawn}",
            f"{pstd[2]:.4f} mm",
            mm(TOLERANCE_POSITION_MM, 2),
            along_state,
            ""
            if along_state == DETERMINED
            else "time of flight sees the tool's length and the touched plate's height as one "
            "quantity: plate points known to better than 0.05 mm ([reflector] points_std_mm) "
            "would determine it",
        ),
        Quantity(
            "beam direction (rx, ry)",
            f"{rot[0]:.4f}°, {rot[1]:.4f}°{drawn}",
            f"{rstd[0]:.4f}°, {rstd[1]:.4f}°",
            deg(TOLERANCE_BEAM_DEG, 2),
            direction_state,
            "" if direction_state == DETERMINED else run,
        ),
        Quantity(
            "rotation about the beam (rz)",
            f"{rot[2]:.4f}°",
            f"{rstd[2]:.4f}°",
            deg(TOLERANCE_BEAM_DEG, 2),
            about_state,
            ""
            if about_state == DETERMINED
            else "an echo does not see it (kept from the drawing within its tolerance); "
            "a feature off the beam's axis would determine it",
        ),
    ]


# ---------------------------------------------------------------------------------------------
# verify


def verify_verdict(facts: VerifyFacts) -> str:
    """The verdict as verify gave it: ``PASSED``, ``PASSED (marginal)``, ``FAILED``..."""
    return ("PASSED" if facts.passed else "FAILED") + (" (marginal)" if facts.marginal else "")


def verify_words(facts: VerifyFacts) -> str:
    """The verdict and its terms in one sentence (plain text)."""
    sign = "≤" if facts.worst_mm <= facts.tolerance_mm else ">"
    text = (
        f"verify {verify_verdict(facts)}: largest deviation {facts.worst_mm:.3f} mm {sign} "
        f"tolerance {facts.tolerance_mm:g} mm over {facts.points} points (block axes)"
    )
    if facts.marginal:
        room = abs(facts.tolerance_mm - facts.worst_mm)
        text += (
            f"; verify measures to ±{facts.measured_within_mm:.2f} mm, more than the "
            f"{room:.3f} mm between them: the {'pass' if facts.passed else 'failure'} is not "
            "determined"
        )
    return text


def verify_state(v: VerifyPicture | None, r: CellReport) -> tuple[str, str]:
    """What the page says of verify: a short verdict and a sentence (plain text)."""
    if v is None:
        return "not verified", "no verify on this cell: `ucal verify PROFILE` measures it"
    if v.facts is None:
        return (
            "see the picture",
            "the picture beside the profile was drawn by a ucal that records no facts in it: "
            "its title holds the verdict",
        )
    text = f"on {v.facts.cell_words}, {v.modified.strftime('%Y-%m-%d %H:%M UTC')}: " + (
        verify_words(v.facts)
    )
    if v.facts.profile_sha256 != r.profile_sha256:
        ids = ", ".join(f"#{w.entry.id} ({w.command})" for w in v.writes_since)
        text += (
            "; the profile was written since"
            + (f" ({ids})" if ids else "")
            + ": it verified an earlier version, `ucal verify` again verifies this one"
        )
    return verify_verdict(v.facts), text


def would_determine_verify(facts: VerifyFacts, r: CellReport) -> str:
    """What would settle a marginal verify: the DH table identified, else more points."""
    if not r.identified_dh:
        return "identifying the DH table (`ucal calibrate --level full`) would determine it"
    return "what the notes under the picture name would determine it"
