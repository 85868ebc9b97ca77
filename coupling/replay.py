"""Replay: re-run one participant alone on recorded interface data.

With ``record_data = true`` a scheme records, for every solve, the inputs a
participant received and the outputs it returned (and, in time-dependent
runs, its checkpoint at the window start).  :func:`replay` feeds the recorded
inputs of one iteration to a participant again and compares its outputs with
the recorded ones, to find out which side breaks a coupling (e.g. a solver
that is not deterministic, depends on hidden state, or fails on the data of
one particular iteration).

Example::

    scheme = cp.build_scheme({..., "record_data": True}, [fluid, gel], data)
    try:
        scheme.solve()
    except cp.CouplingDivergedError:
        pass
    scheme.recording.save("recording.npz")        # optional, for another session
    out = cp.replay(gel, scheme.recording, iteration=7)
    print(out.max_abs_difference)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from coupling.participant import Participant, uses_advance
from coupling.records import Recording

__all__ = ["ReplayResult", "replay"]


@dataclass
class ReplayResult:
    """Outputs of a replayed solve and their difference to the recording.

    Attributes:
        participant: Participant name.
        window: Window index of the replayed solve.
        iteration: Iteration of the replayed solve.
        inputs: The recorded inputs that were fed to the participant.
        outputs: The new outputs.
        recorded_outputs: The recorded outputs.
        difference: ``outputs - recorded_outputs`` per data.
    """

    participant: str
    window: int
    iteration: int
    inputs: dict[str, np.ndarray]
    outputs: dict[str, np.ndarray]
    recorded_outputs: dict[str, np.ndarray]
    difference: dict[str, np.ndarray]

    @property
    def max_abs_difference(self) -> dict[str, float]:
        """Data name -> ``max |outputs - recorded|``."""
        return {k: float(np.max(np.abs(v))) if v.size else 0.0 for k, v in self.difference.items()}

    @property
    def relative_difference(self) -> dict[str, float]:
        """Data name -> ``‖outputs - recorded‖ / ‖recorded‖`` (0 if both vanish)."""
        out = {}
        for k, diff in self.difference.items():
            num = float(np.linalg.norm(diff))
            den = float(np.linalg.norm(self.recorded_outputs[k]))
            out[k] = 0.0 if num == 0.0 else (num / den if den > 0.0 else float("inf"))
        return out


def replay(participant: Participant, recording: Recording, iteration: int,
           window: int | None = None, restore_state: bool = True) -> ReplayResult:
    """Re-run ``participant`` alone on the inputs it received in ``iteration``.

    Args:
        participant: The participant (same name as in the recording).
        recording: A :class:`Recording` (``scheme.recording`` or :meth:`Recording.load`).
        iteration: Iteration (1-based) within the window.
        window: Window index (default: the last recorded window with that iteration).
        restore_state: In time-dependent runs, call ``load_state`` with the
            recorded window checkpoint (if in memory) after ``begin_window(t, dt)``
            (before ``advance(t, dt)`` for a participant of the earlier protocol).

    Returns:
        The :class:`ReplayResult`.

    Raises:
        KeyError: If nothing is recorded for that participant and iteration,
            or the participant does not return a recorded data.
    """
    solve = recording.find(participant.name, iteration, window)
    if solve.dt is not None:
        key = (solve.window, participant.name)
        restore = restore_state and key in recording.checkpoints
        if uses_advance(participant):        # the earlier protocol: state saved before advance
            if restore:
                participant.load_state(recording.checkpoints[key])
            participant.advance(solve.time, solve.dt)
        else:                                # state saved after begin_window
            participant.begin_window(solve.time, solve.dt)
            if restore:
                participant.load_state(recording.checkpoints[key])
    outputs_raw = participant.solve({k: v.copy() for k, v in solve.inputs.items()})
    outputs: dict[str, np.ndarray] = {}
    difference: dict[str, np.ndarray] = {}
    for name, recorded in solve.outputs.items():
        if name not in outputs_raw:
            raise KeyError(f"replay: participant {participant.name!r} did not return {name!r}")
        value = np.array(outputs_raw[name], dtype=float).reshape(recorded.shape)
        outputs[name] = value
        difference[name] = value - recorded
    return ReplayResult(participant.name, solve.window, solve.iteration,
                        {k: v.copy() for k, v in solve.inputs.items()}, outputs,
                        {k: v.copy() for k, v in solve.outputs.items()}, difference)
