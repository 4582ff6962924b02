"""The training steps' wall-clock times of a finished run, read from the TensorBoard log ns-train
writes into its run folder (``--vis tensorboard``).

nerfstudio logs ``Train Iter (time)`` (seconds) at every step: the whole iteration with the
pipeline's callbacks (the attack's included), without the evaluation passes between steps.
"""

from __future__ import annotations

import statistics
from pathlib import Path

#: The scalar nerfstudio's trainer writes for each step (``EventName.ITER_TRAIN_TIME``).
STEP_TIME_TAG = "Train Iter (time)"


def step_seconds(run_dir: Path) -> list[float]:
    """Seconds of every logged training step of the run in ``run_dir`` (empty: no TensorBoard log,
    or one without step times, e.g. a run trained with ``--vis viewer``)."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    times: list[float] = []
    for events in sorted(Path(run_dir).glob("events.out.tfevents.*")):
        log = EventAccumulator(str(events), size_guidance={"scalars": 0, "images": 1, "tensors": 1})
        try:
            log.Reload()
            if STEP_TIME_TAG in log.Tags().get("scalars", []):
                times += [float(e.value) for e in log.Scalars(STEP_TIME_TAG)]
        except (OSError, ValueError, KeyError):  # a truncated or foreign log: no figure from it
            continue
    return times


def median_step_ms(run_dir: Path) -> float | None:
    """Median training step of the run in ``run_dir``, milliseconds (None: no step times logged)."""
    times = step_seconds(run_dir)
    return round(1000.0 * statistics.median(times), 1) if times else None
