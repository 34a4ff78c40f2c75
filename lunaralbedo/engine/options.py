"""The solver's choices that its command offers before anything heavy is imported (``solve --help``)."""

#: The solver's methods (docs/solver.md): ``overlap`` (exposures from image overlaps, damped phase step)
#: and ``seed`` (the PhotometryTK manual's plain updates).
METHODS = ("overlap", "seed")
#: Early stop: after the first iteration whose Q is within this fraction of the previous Q (docs/solver.md).
DEFAULT_TOLERANCE = 1e-5
