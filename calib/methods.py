"""The calibration methods and term models by name. Kept apart from the maths (no numpy, no scipy) so that a
command line can list them without importing the solvers."""

BASELINES = ("pso", "ekf", "ukf", "gn", "sa", "pf", "de")  # the paper's M1-M7 (calib.baselines)
METHODS = BASELINES + ("lmlc",)  # M8: calib.calibrate.robust_fit
ALL_METHODS = METHODS + ("mcs-lmlc",)  # M9: LMLC on the configurations MCS selects
TERM_MODELS = ("geometric", "compliance", "full", "auto")  # joint-space terms beside the table
DEFAULT_TERM_MODEL = "auto"  # what `station calibrate` and the demo fit (the running calibration: geometric)
