"""The full level's stiffness as ``calibrate`` prints it without ``--json``: the identified
joint's stiffness and std, each other joint said not determined with its reason, and what
would separate the ones the readings measured but did not determine."""

from __future__ import annotations

from rich.console import Console

from ucal.cli.calibrate import show_stiffness
from ucal.model.stiffness import JointStiffness


def test_the_identified_stiffness_and_why_the_others_are_not() -> None:
    held = "its torque does not change over the postures (or nothing weighs)"
    found = (
        JointStiffness(1, 1.59, None, 1.59, 1.0, None, "not determined", held),
        JointStiffness(2, 3.5, 0.1, 3.9, 2.5, 4.8, "identified"),
        JointStiffness(3, 1.9, 1.0, 3.9, 2.5, 55.0, "not determined", "its std (55 %)"),
    )
    console = Console(record=True, width=200)
    show_stiffness(console, found)
    text = console.export_text()
    j2 = next(line for line in text.splitlines() if "J2" in line)
    assert "2.857e+05" in j2 and "4.8" in j2 and "identified" in j2
    assert f"J1 stiffness not determined: {held}" in text
    assert "J3 stiffness not determined: its std (55 %)" in text
    # what would separate it, for the joint the readings measured (not J1, which they do not)
    note = " ".join(text.split("\nstiffness of ", 1)[1].split())
    assert note.startswith("J3 not determined") and "mass added to the holder" in note
