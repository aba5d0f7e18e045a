"""Stage timing and progress reports of long runs."""
import sys
import time

#: The ``(iteration, iterations)`` a :class:`Clock` or a round of tasks is given for the passes
#: over a file before the plan exists: reported as iteration 0 of 0.
BEFORE = (-1, 0)
#: The column of the stage names in ``progress=True``'s lines: the longest with its run
#: number (``"refine_neighbors #2"``).
STAGE_WIDTH = 19


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
    less the time already spent in the current one; there is none before the first iteration
    has finished, nor within half a second of the estimate's end or past it (the default
    method's last iteration also tests and refits: "about 0 s left" would be said for most of
    a run).
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
            if self.iteration:  # the passes over a file before the plan are no iteration
                self.durations.append(self.last - self.iteration_started)
            self.iteration_started = self.last
            self.iteration = iteration
        self.last = now
        left = None
        if self.durations:
            mean = sum(self.durations) / len(self.durations)
            left = mean * (iterations - iteration + 1) - (now - self.iteration_started)
            left = left if left >= 0.5 else None  # never "about 0 s left"
        return now - self.started, left


class Names:
    """Each reported stage's name, numbered from its second run in one iteration (the
    refinement's iterations run within the method's last: ``"refine_fit #2"``)."""

    def __init__(self):
        self.runs = {}

    def __call__(self, iteration, stage):
        runs = self.runs[iteration, stage] = self.runs.get((iteration, stage), 0) + 1
        return stage if runs == 1 else f"{stage} #{runs}"


def label(iteration, iterations):
    """``"iteration 1/2"``, or ``"preparing"`` for the passes over a file before the plan
    (iteration 0, :data:`BEFORE`)."""
    return f"iteration {iteration}/{iterations}" if iteration else "preparing"


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
        clock, names = TimeLeft(), Names()

        def show(iteration, iterations, stage, seconds):
            times = describe(*clock(iteration, iterations, seconds))
            sys.stderr.write(f"pssd_fast: {label(iteration, iterations):<15s} "
                             f"{names(iteration, stage):<{STAGE_WIDTH}s} {seconds:8.3f} s "
                             f"({times})\n")
            sys.stderr.flush()
        return show
    if not callable(progress):
        raise TypeError(f"progress must be True, False, None or a callable; got {progress!r}")
    return progress
