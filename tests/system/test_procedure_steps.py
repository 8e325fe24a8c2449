"""The moving commands follow one procedure: the same steps in the same order, against the
simulated cell, with the plan shown (with its estimated duration) and progress reported with
the time left."""

from __future__ import annotations

import contextlib
import itertools
import shutil
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from ucal.calibration.procedure import FullCalibration, OffsetsCalibration
from ucal.cell_choice import CellChoice
from ucal.procedure import MeasuringProcedure, Outcome, RunOptions, Step
from ucal.profile import load_profile
from ucal.progress import Progress
from ucal.toolframe.procedure import ToolFrameCalibration
from ucal.verify.procedure import VerifyJob
from ucal.verify.region import RegionJob

pytestmark = pytest.mark.system

EXAMPLE = Path(__file__).parents[2] / "profiles" / "example_cell.toml"


class Recorder:
    """A presenter that keeps what the technician would see, and the steps."""

    def __init__(self) -> None:
        self.events: list[Any] = []
        self.progress_seen: list[Progress] = []

    def show_plan(self, text: str) -> None:
        self.events.append(("plan", text))

    def confirm(self, cell: CellChoice) -> None:
        self.events.append(("confirm", cell.name))

    @contextlib.contextmanager
    def progress(self, title: str) -> Iterator[Callable[[Progress], None]]:
        self.events.append(("progress", title))
        yield self.progress_seen.append


def run(
    job: Any, dry_run: bool = False, world: str = ""
) -> tuple[list[Any], Recorder, Outcome[Any]]:
    steps: list[Step] = []
    presenter = Recorder()
    options = RunOptions(CellChoice(world, None, None), yes=False, dry_run=dry_run)
    outcome = MeasuringProcedure(job, options, presenter, on_step=steps.append).run()
    return steps, presenter, outcome


@pytest.fixture
def profile_path(tmp_path: Path) -> Path:
    path = tmp_path / "cell.toml"
    shutil.copy(EXAMPLE, path)
    return path


def check_run(steps: list[Step], presenter: Recorder, outcome: Outcome[Any], title: str) -> None:
    assert steps == list(Step)  # check, plan, show, confirm, open, measure, solve, write, result
    kinds = [e[0] for e in presenter.events]
    assert kinds == ["plan", "confirm", "progress"]
    assert "Estimated time on a real cell" in presenter.events[0][1]
    assert presenter.events[1] == ("confirm", "the simulated cell")
    assert presenter.events[2] == ("progress", title)
    seen = presenter.progress_seen
    # every step reported in order with its counters, the time left falling to 0 at the end
    assert [p.step.done for p in seen] == list(range(len(seen)))
    assert seen[-1].step.what == "solving" and seen[-1].left_s == 0.0
    assert all(a.moves <= b.moves and a.reads <= b.reads for a, b in itertools.pairwise(seen))
    assert seen[0].left_s > seen[len(seen) // 2].left_s > 0.0
    assert isinstance(outcome.to_json(), dict) and outcome.command == title


def test_calibrate_tool_frame_and_verify_go_through_the_same_steps(profile_path: Path) -> None:
    before = profile_path.read_bytes()
    profile = load_profile(profile_path)
    steps, presenter, outcome = run(OffsetsCalibration(profile, profile_path), dry_run=True)
    check_run(steps, presenter, outcome, "calibrate")
    assert {p.step.face for p in presenter.progress_seen[:-1]} == {"XY", "YZ", "XZ"}
    assert presenter.progress_seen[0].step.configuration == "base"
    assert outcome.written is False and profile_path.read_bytes() == before  # a dry run

    steps, presenter, outcome = run(ToolFrameCalibration(profile, profile_path, points=2))
    check_run(steps, presenter, outcome, "tool-frame")
    assert presenter.progress_seen[0].step.face == "plate"
    edges = [p.step.what for p in presenter.progress_seen if p.step.what.startswith("edge")]
    turned = [w for w in edges if w.endswith(", tool turned 180°")]
    assert edges and len(turned) == len(edges) / 2  # each edge scan named in both senses
    assert outcome.written == (not outcome.out_of_tolerance)
    assert outcome.to_json()["written"] == outcome.written

    profile = load_profile(profile_path)  # as tool-frame wrote it
    # A cell as the profile describes it (the calibration above was a dry run: on the demo
    # truth the offsets would be degrees off, and the searches a run longer than its plan)
    world = profile_path.with_name("as_described.toml")
    world.write_text("[noise]\nseed = 3\n", encoding="utf-8")
    steps, presenter, outcome = run(
        VerifyJob(profile, profile_path, n_points=1), dry_run=True, world=str(world)
    )
    check_run(steps, presenter, outcome, "verify")
    assert [p.step.what for p in presenter.progress_seen] == [
        "before point 1",
        "after point 1",
        "tool check along block X",
        "tool check along block Y",
        "solving",
    ]
    assert outcome.written is False and outcome.to_json()["plot"] is None  # a dry run


def test_calibrate_full_goes_through_the_same_steps(profile_path: Path) -> None:
    before = profile_path.read_bytes()
    job = FullCalibration(load_profile(profile_path), profile_path, max_postures=3)
    steps, presenter, outcome = run(job, dry_run=True)
    check_run(steps, presenter, outcome, "calibrate")
    assert "3 postures chosen" in presenter.events[0][1]
    seen = presenter.progress_seen
    configs = [p.step.configuration for p in seen[:-1]]
    # never calibrated: the offsets level's faces first, then the postures
    assert configs[-3:] == ["p01", "p02", "p03"] and configs[0] == "base"
    assert {str(c) for c in configs[:-3]} == {"base", "j3", "j2", "j1"}
    assert [p.step.done for p in seen] == list(range(len(seen)))  # of one total
    assert all(p.step.face in {"XY", "YZ", "XZ", "step"} for p in seen[:-1])
    assert outcome.to_json()["level"] == "full" and outcome.to_json()["plan"]["postures"] == 3
    assert outcome.to_json()["moves"] == seen[-1].moves
    assert outcome.written is False and profile_path.read_bytes() == before  # a dry run


def test_verify_region_goes_through_the_same_steps(profile_path: Path) -> None:
    before = profile_path.read_bytes()
    job = RegionJob(load_profile(profile_path), profile_path, n_postures=3)
    steps, presenter, outcome = run(job)
    check_run(steps, presenter, outcome, "verify")
    assert "Region check of" in presenter.events[0][1]
    seen = presenter.progress_seen
    assert [p.step.configuration for p in seen[:-1]] == ["r01", "r02", "r03"]
    assert outcome.to_json()["region"]["postures"] == 3
    assert outcome.written is False and profile_path.read_bytes() == before  # never written
