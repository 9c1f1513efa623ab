"""``activetouch collect`` on the simulated rig: designs, files, usage errors, faults."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from typer.testing import CliRunner

from app.cli.main import app
from app.documents.raw_touches import featurise, read_raw_touches
from app.documents.training_csv import read_training_csv
from app.errors import BadInputError
from app.rig import build
from app.rig.build import RigHandle
from app.services.collections import check_objects, iter_collection
from core.evaluation.designs import CollectionDesign, random_design, shared_design
from core.features.pipeline import means_pipeline
from core.gp.kronecker import find_shared_design
from hardware.clock import VirtualClock
from hardware.errors import ServoHardwareErrorFlags
from hardware.sim.rig import SimulatedRig, in_process_rig
from tests.conftest import SETTLE_S

runner = CliRunner()
pytestmark = pytest.mark.usefixtures("cli_rig_rest")  # 5 s before each touch, not 20 s


def said(result: Any) -> str:
    """What the command printed, with rich's line wrapping undone."""
    return " ".join(result.output.split())


#: Short touches keep the tests fast (the teaching trajectory needs ≥ 5 s to respect limits).
FAST = ["--duration", "5"]
OBJECTS = ["--object", "paper_cup", "--object", "stainless_cup", "--object", "sponge=6"]
NAMES = ("paper_cup", "stainless_cup", "sponge")
DX, DY = 7, 5  # the six DMP components and the press depth (collect's default)


def collect(*args: str) -> Any:
    return runner.invoke(app, ["collect", "--sim", *FAST, *args])


def test_random_design_writes_the_csv_the_raw_series_and_a_summary(tmp_path: Path) -> None:
    out, raw = tmp_path / "data.csv", tmp_path / "raw.jsonl"
    result = collect(
        *OBJECTS, "--design", "random", "--touches", "3", "--placements", "3", "--seed", "1",
        "--out", str(out), "--raw", str(raw), "--json",
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    assert summary["complete"] is True
    assert summary["error"] is None
    assert summary["recorded"] == summary["planned"] == 9
    assert summary["fit_ready"] is True
    assert summary["objects"] == [
        {"name": "paper_cup", "slot": 0, "touches": 3},
        {"name": "stainless_cup", "slot": 3, "touches": 3},
        {"name": "sponge", "slot": 6, "touches": 3},
    ]
    assert summary["channels"][3] == "heat_flux_mw"
    data = read_training_csv(out.read_text())
    assert data.object_names == NAMES
    # The paper's design from core.evaluation.designs, written exactly; with a placement per touch
    # it is touched in rounds (each object's next action in turn).
    expected = random_design(3, 3, np.zeros(DX), np.eye(DX), np.random.default_rng(1))
    np.testing.assert_array_equal(data.object_index, [0, 1, 2] * 3)
    for obj in range(3):
        np.testing.assert_array_equal(
            data.actions[data.object_index == obj],
            expected.actions[expected.object_index == obj],
        )
    assert find_shared_design(data) is None
    # The steel cup drains heat from the warm fingertip; the paper cup barely does.
    heat = data.observations[:, 3]
    assert heat[data.object_index == 1].min() > 2 * heat[data.object_index == 0].max()
    lines = [json.loads(line) for line in raw.read_text().splitlines()]
    assert [line["object"] for line in lines] == [NAMES[i] for i in data.object_index]
    for line in lines:
        # Each series once, in its channel: no frames beside it.
        assert "tactile" not in line and "channel_names" not in line  # noqa: PT018
        assert abs(line["n_frames"] - 500) <= 2  # 5 s at 100 frames/s
        assert len(line["tactile_times_s"]) == line["n_frames"]
        assert len(line["channels"]) == DY
        for channel in line["channels"].values():
            assert len(channel["samples"]) == line["n_frames"]
    # The file is a raw-touch file: the channel-means pipeline gives the CSV's y.
    touches = read_raw_touches(raw.read_text())
    assert touches.channel_names == tuple(summary["channels"])
    assert abs(touches.touches[0].channels[0].rate_hz - 100.0) < 0.5
    np.testing.assert_array_equal(touches.actions, data.actions)
    means = featurise(touches, means_pipeline(touches.touches[0]))
    np.testing.assert_allclose(means.observations, data.observations, rtol=1e-12)


def test_shared_design_touches_every_object_with_the_same_actions(tmp_path: Path) -> None:
    out = tmp_path / "shared.csv"
    result = collect(
        *OBJECTS[:4], "--design", "shared", "--touches", "4", "--placements", "4", "--seed", "2",
        "--action-scale", "0.5", "--out", str(out), "--json",
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    data = read_training_csv(out.read_text())
    # A placement per touch: round by round, every object in turn; each object gets every action
    # once, in its own random order (seeded), so one action's touches do not follow each other.
    assert [data.object_names[i] for i in data.object_index] == ["paper_cup", "stainless_cup"] * 4
    expected = shared_design(
        2, 4, np.zeros(DX), 0.25 * np.eye(DX), np.random.default_rng(2)
    ).actions[:4]
    first, second = data.actions[0::2], data.actions[1::2]
    for touched in (first, second):
        np.testing.assert_array_equal(np.unique(touched, axis=0), np.unique(expected, axis=0))
    assert not np.array_equal(first, second)  # not action-major
    assert find_shared_design(data) is not None  # the fit can take the Kronecker path


def test_the_spread_defaults_to_the_simulated_tables_own(tmp_path: Path) -> None:
    # cushions: action_std 1.5 (deep presses reach the inserts); --action-scale overrides it.
    out = tmp_path / "c.csv"
    base = ["--table", "cushions", "--touches", "2", "--seed", "4", "--json", "--force"]
    result = collect(*base, "--out", str(out))
    assert result.exit_code == 0, result.output
    assert json.loads(result.stdout)["action_scale"] == 1.5
    data = read_training_csv(out.read_text())
    n = len(data.object_names)
    expected = random_design(n, 2, np.zeros(DX), 2.25 * np.eye(DX), np.random.default_rng(4))
    for obj in range(n):
        np.testing.assert_array_equal(
            data.actions[data.object_index == obj],
            expected.actions[expected.object_index == obj],
        )
    given = collect(*base, "--action-scale", "0.5", "--out", str(out))
    assert given.exit_code == 0, given.output
    assert json.loads(given.stdout)["action_scale"] == 0.5


def test_adaptive_design_spends_the_same_budget_in_planned_rounds(tmp_path: Path) -> None:
    out = tmp_path / "adaptive.csv"
    result = collect(
        *OBJECTS[:4], "--design", "adaptive", "--touches", "6", "--seed", "1", "--out", str(out),
        "--json",
    )  # fmt: skip
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    assert summary["recorded"] == summary["planned"] == 12
    data = read_training_csv(out.read_text())
    assert np.bincount(data.object_index).tolist() == [6, 6]  # each object equally
    # The first half: the random design; then rounds (2 and 1 actions), each action on both.
    expected = random_design(2, 3, np.zeros(DX), np.eye(DX), np.random.default_rng(1))
    for obj in range(2):
        np.testing.assert_array_equal(
            data.actions[data.object_index == obj][:3],
            expected.actions[expected.object_index == obj],
        )
    rounds = [data.actions[data.object_index == obj][3:] for obj in range(2)]
    for span in (slice(0, 2), slice(2, 3)):  # each round's actions on both (in any order)
        np.testing.assert_array_equal(
            np.unique(rounds[0][span], axis=0), np.unique(rounds[1][span], axis=0)
        )
    too_few = collect(
        *OBJECTS[:4], "--design", "adaptive", "--touches", "2", "--out", str(tmp_path / "b")
    )
    assert too_few.exit_code == 2
    assert "too few for --design adaptive" in said(too_few)


def test_without_design_adaptive_is_the_default_and_random_its_said_fallback(
    tmp_path: Path,
) -> None:
    # The default of docs/usage.md: adaptive (here 3 random touches, then rounds of 2 and 1).
    out = tmp_path / "default.csv"
    result = collect(*OBJECTS[:4], "--touches", "6", "--seed", "1", "--out", str(out), "--json")
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    assert summary["design"] == "adaptive"
    assert summary["design_note"] is None
    data = read_training_csv(out.read_text())
    rounds = [data.actions[data.object_index == obj][3:] for obj in range(2)]
    for span in (slice(0, 2), slice(2, 3)):  # each round's actions on both (in any order)
        np.testing.assert_array_equal(
            np.unique(rounds[0][span], axis=0), np.unique(rounds[1][span], axis=0)
        )  # planned rounds: each action on both
    # Too few touches for a round: random, and the output says so.
    few = collect(*OBJECTS[:4], "--touches", "2", "--out", str(tmp_path / "few.csv"), "--json")
    assert few.exit_code == 0, few.output
    summary = json.loads(few.stdout)
    assert summary["design"] == "random"
    assert "needs 3 touches per object or more (received 2)" in summary["design_note"]
    assert "the random design is used" in said(few)
    # Placements: each adaptive stage needs its own, so fewer than its 3 stages is bad usage.
    placed = collect(
        *OBJECTS[:4], "--touches", "4", "--placements", "2", "--out", str(tmp_path / "p.csv"),
        "--json",
    )  # fmt: skip
    assert placed.exit_code == 2
    assert "--placements: must lie in 3..4" in said(placed)
    assert "3 stages" in said(placed)
    assert not (tmp_path / "p.csv").exists()


def test_same_seed_same_file_and_no_silent_overwrite(tmp_path: Path) -> None:
    out = tmp_path / "a.csv"
    args = [*OBJECTS[:4], "--touches", "2", "--seed", "5", "--out", str(out)]
    assert collect(*args).exit_code == 0
    first = out.read_text()
    refused = collect(*args)
    assert refused.exit_code == 2
    assert "exists; use --force" in said(refused)
    assert out.read_text() == first
    again = collect(*args, "--force")
    assert again.exit_code == 0, again.output
    assert out.read_text() == first  # deterministic for a seed (virtual clock)
    other = collect(*args[:-4], "--seed", "6", "--out", str(out), "--force")
    assert other.exit_code == 0
    assert out.read_text() != first


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["--object", "mug"], "only a simulated rig knows"),
        (["--object", "mug=x", "--object", "b=1"], "the slot must be an integer"),
        (["--object", "=1"], "the name is empty"),
        (["--object", "mug=0"], "at least two --object"),
    ],
)
def test_real_rig_usage_errors(tmp_path: Path, args: list[str], fragment: str) -> None:
    ports = ["--turntable-port", "/dev/null-a", "--finger-port", "/dev/null-b"]
    result = runner.invoke(
        app,
        ["collect", *ports, "--tactile-port", "/dev/null-c", *args, "--out", str(tmp_path / "x")],
    )
    assert result.exit_code == 2
    assert fragment in said(result)
    assert not (tmp_path / "x").exists()


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["--object", "teapot"], "not on the simulated table; it holds paper_cup"),
        (["--object", "paper_cup"], "at least 2 objects, received 1"),
        (["--object", "a=1", "--object", "b=1"], "own slot; repeated: [1]"),
        (["--object", "a=1", "--object", "a=2"], "own name; repeated: ['a']"),
        (["--object", "a=1", "--object", "b=12"], "slot: expected 0..9, received 12"),
        (["--action-scale", "0"], "--action-scale: must be > 0"),
        (["--duration", "1"], "planned touch 1 (paper_cup, x = ["),
        (["--action-scale", "60"], "would be refused"),
    ],
)
def test_simulated_rig_usage_errors(tmp_path: Path, args: list[str], fragment: str) -> None:
    out = tmp_path / "x.csv"
    result = runner.invoke(app, ["collect", "--sim", *args, "--out", str(out)])
    assert result.exit_code == 2
    assert fragment in said(result)
    assert not out.exists()


def test_missing_ports_is_a_usage_error(tmp_path: Path) -> None:
    result = runner.invoke(app, ["collect", "--out", str(tmp_path / "x.csv")])
    assert result.exit_code == 2
    assert "missing --turntable-port, --finger-port, --tactile-port" in said(result)


class TriggerClock(VirtualClock):
    """A virtual clock that calls ``action`` once, when simulated time passes ``at_s``."""

    def __init__(self, at_s: float) -> None:
        super().__init__()
        self.at_s = at_s
        self.action: Callable[[], None] | None = None

    def sleep(self, duration_s: float) -> None:
        super().sleep(duration_s)
        if self.action is not None and self.now() > self.at_s:
            action, self.action = self.action, None
            action()


@pytest.fixture
def rig_with_trigger(monkeypatch: pytest.MonkeyPatch) -> dict[str, Any]:
    """``collect --sim`` opens a simulated rig whose clock fires an action 13 s after the rest
    before the first touch (after the first touch, before the last)."""
    made: dict[str, Any] = {"clock": TriggerClock(at_s=SETTLE_S + 13.0)}

    def open_rig(**kwargs: Any) -> RigHandle:
        simulation: SimulatedRig = in_process_rig(
            seed=kwargs.get("seed", 0), clock=made["clock"], rig_config=kwargs.get("rig_config")
        )
        made["simulation"] = simulation
        return RigHandle(simulation.rig, simulation)

    monkeypatch.setattr(build, "open_rig", open_rig)
    return made


def test_a_fault_mid_collection_keeps_what_was_recorded(
    tmp_path: Path, rig_with_trigger: dict[str, Any]
) -> None:
    def overload() -> None:
        plant = rig_with_trigger["simulation"].devices.plant
        plant.inject_hardware_error(0, ServoHardwareErrorFlags.OVERLOAD)

    rig_with_trigger["clock"].action = overload
    out, raw = tmp_path / "data.csv", tmp_path / "raw.jsonl"
    result = collect(
        *OBJECTS, "--design", "random", "--touches", "4", "--out", str(out), "--raw", str(raw),
        "--json",
    )  # fmt: skip
    assert result.exit_code == 1
    summary = json.loads(result.stdout)
    assert summary["complete"] is False
    assert "ServoHardwareError" in summary["error"]
    assert "OVERLOAD" in summary["error"]
    assert summary["rig_state"] == "fault"
    assert 1 <= summary["recorded"] < summary["planned"] == 12
    assert "collection stopped" in said(result)
    rows = out.read_text().splitlines()
    assert rows[0] == (
        "object,placement,time_s,duration_s,x_1,x_2,x_3,x_4,x_5,x_6,x_7,y_1,y_2,y_3,y_4,y_5"
    )
    assert len(rows) == 1 + summary["recorded"]
    assert len(raw.read_text().splitlines()) == summary["recorded"]
    # The rig stopped safely: the faulty servo and the other one are switched off.
    plant = rig_with_trigger["simulation"].devices.plant
    assert not plant.joint_state(0)[3]
    assert not plant.joint_state(1)[3]


def test_ctrl_c_emergency_stops_and_keeps_the_file(
    tmp_path: Path, rig_with_trigger: dict[str, Any]
) -> None:
    def interrupt() -> None:
        raise KeyboardInterrupt

    rig_with_trigger["clock"].action = interrupt
    out = tmp_path / "data.csv"
    result = collect(*OBJECTS, "--design", "random", "--touches", "4", "--out", str(out), "--json")
    assert result.exit_code == 130
    summary = json.loads(result.stdout)
    assert summary["rig_state"] == "estopped"
    assert "interrupted" in summary["error"]
    assert len(out.read_text().splitlines()) == 1 + summary["recorded"]
    assert summary["recorded"] >= 1


def test_iter_collection_checks_the_design_against_the_objects() -> None:
    design = CollectionDesign(
        object_index=np.array([0, 0, 1, 2]), actions=np.zeros((4, DX)), shared=False
    )
    with pytest.raises(BadInputError, match="touches object 2, but only 2 objects"):
        next(iter_collection(None, None, {"a": 0, "b": 1}, design))  # type: ignore[arg-type]
    uneven = CollectionDesign(
        object_index=np.array([0, 0, 1]), actions=np.zeros((3, DX)), shared=True
    )
    with pytest.raises(BadInputError, match=r"the objects have \[1, 2\] actions"):
        next(iter_collection(None, None, {"a": 0, "b": 1}, uneven))  # type: ignore[arg-type]
    check_objects({"a": 0, "b": 1})
    with pytest.raises(BadInputError, match="own slot"):
        check_objects([("a", 0), ("b", 0)])
