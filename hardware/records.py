"""What a touch records: the raw tactile series, the joint states and the observation y."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from hardware.errors import HardwareError

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


@dataclass(frozen=True)
class TouchRecord:
    """One touch: the commanded trajectory, the tactile stream and the joint states.

    Times are seconds from the start of the commanded trajectory. A record attached to an error
    (``HardwareError.partial_record``) has ``complete = False`` and holds everything received up
    to the failure.

    Attributes:
        slot: Turntable slot touched (None if unknown).
        channel_names: Names of the tactile channels. Length C.
        joint_names: Names of the joints. Length J.
        dt_s: Control period of the trajectory.
        commanded_deg: The trajectory sent. Shape (T, J).
        tactile_times_s: Time of each tactile frame. Shape (n,).
        tactile: Tactile frames. Shape (n, C).
        tactile_sequence: Frame sequence numbers. Shape (n,).
        joint_times_s: Time of each joint-state read. Shape (m,).
        joint_positions_deg: Present positions. Shape (m, J).
        joint_currents_ma: Present currents. Shape (m, J).
        dropped_frames: Frames missing from the sequence numbers during the touch.
        corrupt_frames: Frames rejected (bad CRC or malformed) during the touch.
        discarded_bytes: Bytes skipped while resynchronising.
        late_steps: Setpoints skipped because the control loop ran late.
        complete: Whether the touch ran to its end.
        failure: Why it did not (the error message), else None.
        started_s: When the commanded trajectory started, on the rig's clock (``rig.clock``:
            simulated seconds on a simulated rig), or None if it never started. The touch-local
            times above count from it; comparing it across touches tells how far apart in time
            they were made (the slow drift of the sensor and the room is shared by touches
            made close together).
    """

    slot: int | None
    channel_names: tuple[str, ...]
    joint_names: tuple[str, ...]
    dt_s: float
    commanded_deg: FloatArray
    tactile_times_s: FloatArray
    tactile: FloatArray
    tactile_sequence: IntArray
    joint_times_s: FloatArray
    joint_positions_deg: FloatArray
    joint_currents_ma: FloatArray
    dropped_frames: int = 0
    corrupt_frames: int = 0
    discarded_bytes: int = 0
    late_steps: int = 0
    complete: bool = True
    failure: str | None = None
    started_s: float | None = None

    def __post_init__(self) -> None:
        n_channels = len(self.channel_names)
        n_joints = len(self.joint_names)
        checks = (
            ("commanded_deg", self.commanded_deg, 2, n_joints),
            ("tactile", self.tactile, 2, n_channels),
            ("joint_positions_deg", self.joint_positions_deg, 2, n_joints),
            ("joint_currents_ma", self.joint_currents_ma, 2, n_joints),
        )
        for name, array, ndim, width in checks:
            if np.ndim(array) != ndim or np.shape(array)[1] != width:
                raise HardwareError(
                    f"TouchRecord.{name}: expected shape (n, {width}), received {np.shape(array)}."
                )
        n = len(self.tactile)
        if len(self.tactile_times_s) != n or len(self.tactile_sequence) != n:
            raise HardwareError(
                f"TouchRecord: {n} tactile frames but {len(self.tactile_times_s)} times and "
                f"{len(self.tactile_sequence)} sequence numbers."
            )
        m = len(self.joint_positions_deg)
        if len(self.joint_times_s) != m or len(self.joint_currents_ma) != m:
            raise HardwareError(
                f"TouchRecord: {m} joint positions but {len(self.joint_times_s)} times and "
                f"{len(self.joint_currents_ma)} currents."
            )
        if self.started_s is not None and not math.isfinite(self.started_s):
            raise HardwareError(
                f"TouchRecord.started_s: must be finite, received {self.started_s}."
            )
        for name in (
            "commanded_deg",
            "tactile_times_s",
            "tactile",
            "tactile_sequence",
            "joint_times_s",
            "joint_positions_deg",
            "joint_currents_ma",
        ):
            getattr(self, name).flags.writeable = False

    @property
    def n_frames(self) -> int:
        """Number of tactile frames recorded."""
        return int(self.tactile.shape[0])

    @property
    def duration_s(self) -> float:
        """Duration of the commanded trajectory."""
        return float((self.commanded_deg.shape[0] - 1) * self.dt_s)

    @property
    def observation(self) -> FloatArray:
        """y: the mean of each tactile channel over the touch (paper, Exp. 2). Shape (C,).

        Raises:
            HardwareError: No frame was recorded.
        """
        if self.n_frames == 0:
            raise HardwareError("the touch recorded no tactile frame; it has no observation.")
        return np.asarray(self.tactile.mean(axis=0), dtype=np.float64)
