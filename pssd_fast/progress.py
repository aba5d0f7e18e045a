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
        """``func(*args)``, timed as ``stage``."""
        started = time.perf_counter()
        result = func(*args)
        self.times[stage] = time.perf_counter() - started
        if self.report is not None:
            self.report(self.iteration + 1, self.iterations, stage, self.times[stage])
        return result


def reporter(progress):
    """``None``/``False``: silent; ``True``: a line per stage on stderr; else the callable."""
    if progress is None or progress is False:
        return None
    if progress is True:
        def show(iteration, iterations, stage, seconds):
            sys.stderr.write(f"pssd_fast: iteration {iteration}/{iterations} {stage:<10s} "
                             f"{seconds:8.3f} s\n")
            sys.stderr.flush()
        return show
    if not callable(progress):
        raise TypeError(f"progress must be True, False, None or a callable; got {progress!r}")
    return progress
