"""Stage timing and progress reports of long runs."""
import sys
import time


class Clock:
    """Times the stages of one iteration and reports each to the progress callback."""

    def __init__(self, report, iteration, iterations):
        self.times = {}
        self.report = report
        self.iteration = iteration
        self.iterations = iterations

    def run(self, stage, func, *args):
        """``func(*args)``, timed as ``stage`` (added to the stage's earlier runs)."""
        started = time.perf_counter()
        result = func(*args)
        self.add(stage, time.perf_counter() - started)
        return result

    def add(self, stage, seconds):
        """A stage timed elsewhere (in a tile's task): added to the stage's earlier runs and
        reported."""
        self.times[stage] = self.times.get(stage, 0.0) + seconds
        if self.report is not None:
            self.report(self.iteration + 1, self.iterations, stage, seconds)


class TimeLeft:
    """Elapsed time of a run and an estimate of the time left, from the reports of its stages.

    The estimate is the mean duration of the finished iterations times the iterations left,
    less the time already spent in the current one; there is none during the first iteration.
    """

    def __init__(self):
        self.started = None
        self.iteration = None
        self.iteration_started = None
        self.last = None
        self.durations = []

    def __call__(self, iteration, iterations, seconds):
        """Record a finished stage; return ``(elapsed, left)``, ``left`` None if unknown."""
        now = time.perf_counter()
        if self.started is None:
            self.started = self.iteration_started = now - seconds
            self.iteration = iteration
        elif iteration != self.iteration:
            self.durations.append(self.last - self.iteration_started)
            self.iteration_started = self.last
            self.iteration = iteration
        self.last = now
        left = None
        if self.durations:
            mean = sum(self.durations) / len(self.durations)
            left = max(0.0, mean * (iterations - iteration + 1) - (now - self.iteration_started))
        return now - self.started, left


def describe(elapsed, left):
    """``"elapsed 12 s, about 30 s left"`` (without the estimate when there is none)."""
    text = f"elapsed {elapsed:.0f} s"
    return text if left is None else f"{text}, about {left:.0f} s left"


def reporter(progress):
    """``None``/``False``: silent; ``True``: a line per stage on stderr with the elapsed time
    and the time left; else the callable."""
    if progress is None or progress is False:
        return None
    if progress is True:
        clock = TimeLeft()

        def show(iteration, iterations, stage, seconds):
            times = describe(*clock(iteration, iterations, seconds))
            sys.stderr.write(f"pssd_fast: iteration {iteration}/{iterations} {stage:<10s} "
                             f"{seconds:8.3f} s ({times})\n")
            sys.stderr.flush()
        return show
    if not callable(progress):
        raise TypeError(f"progress must be True, False, None or a callable; got {progress!r}")
    return progress
