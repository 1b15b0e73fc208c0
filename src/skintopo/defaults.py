"""The library's defaults and choices as plain values, in one place.

The stage modules take their defaults from here and the command line builds its options
from here, so ``skintopo --help`` needs neither NumPy nor SciPy (the command modules import
the library only when a command runs). Meanings and references are in the modules named.
"""

BANDS = ("red", "green", "blue", "white")  # acquisition: the LED colours (white = all three)
DEFAULT_SATURATION = 0.995  # acquisition: fraction of full scale at or above which a pixel is saturated

SOLVERS = ("least-squares", "robust")  # normals
DEFAULT_SOLVER = "least-squares"
DEFAULT_SHADOW_FRACTION = 0.05  # normals: shadowed below 5% of a first fit's albedo

INTEGRATOR_NAMES = ("dct-poisson", "frankot-chellappa", "least-squares")  # height
AUTO_INTEGRATOR = "auto"
DEFAULT_INTEGRATOR = AUTO_INTEGRATOR

SPECULAR_FREE = "specular-free"  # reconstruct: the SUV specular-free band
HIGHLIGHT_MODES = ("cross-band", "none")
DEFAULT_HIGHLIGHTS = "none"  # cross-band helps opaque shiny surfaces and blue, hurts dark skin green (docs/method.md)

CORRECTION_METHODS = ("paper", "feathered")  # correction
DEFAULT_CORRECTION_METHOD = "paper"

AUTO_HEIGHT = "auto"  # pipeline: which height is measured
PHYSICS = "physics"
HEIGHT_METHODS = (AUTO_HEIGHT, *CORRECTION_METHODS, PHYSICS, *BANDS, SPECULAR_FREE)

DEFAULT_CUTOFF_UM = 8000.0  # segmentation: lambda_c of the band-pass
DEFAULT_SHORT_CUTOFF_UM = 600.0  # segmentation: lambda_s of the band-pass
DEFAULT_MIN_DEPTH_UM = 25.0
DEFAULT_MIN_LENGTH_UM = 1500.0
DEFAULT_STRAIGHT_VALLEY_UM = 1500.0  # segmentation: also find valleys straight over this length (0 = band-pass only)

DEFAULT_FURROW_CLOSING_UM = 200.0  # wrinkles: closing segment that fills the skin's furrows around a wrinkle
DEFAULT_ALONG_CLOSING_UM = 1000.0  # wrinkles: closing segment along a wrinkle that bridges crossing furrows
DEFAULT_DEPTH_WINDOW_UM = 1000.0  # wrinkles: max depth = the deepest stretch of centre line this long
DEFAULT_DEPTH_SHORT_CUTOFF_UM = 0.0  # wrinkles: S-filter of the depth (0 = none: it fills narrow floors)

DEFAULT_COLOUR_SMOOTHING_UM = 30.0  # chromophores: sigma of the Gaussian on the optical densities before the inversion

DEFAULT_PORE_MAX_OPENING_UM = 500.0  # pores: largest opening (the closing segment is 1.2 times this)
DEFAULT_PORE_MIN_OPENING_UM = 40.0  # pores: smallest opening (equivalent diameter at the edge level)
DEFAULT_PORE_MIN_DEPTH_UM = 10.0  # pores: a pore holds a point this deep below its rim
DEFAULT_PORE_EDGE_UM = 0.5  # pores: the opening is where the pit is deeper than this (0.5 um: no false pore on 24 pore-free fields)

DEFAULT_LEVEL_ORDER = 1  # texture: least-squares plane removed first
DEFAULT_P = 10.0  # texture: % (ISO 25178-2 default for Vmp, Vmc, Vvc)
DEFAULT_Q = 80.0  # %

DEFAULT_DETECTION_CONFIDENCE = 0.99  # compare: two-sided prediction limit of a repeat difference (ISO 5725-6's r is the 95% one)

DEFAULT_SCHEDULER_TIMEOUT_S = 10.0  # batch: seconds to wait for a Dask scheduler

DEFAULT_SKIN_OPTICS = "default-v1"  # optics: the simulator's profile (the parameters before profiles existed)

HEIGHT_MAP_SUFFIXES = (".x3p", ".sdf", ".gwy", ".tif", ".tiff", ".npy")  # formats: height maps that can be read

CALIBRATION_TARGETS = ("chrome-sphere", "matte-sphere", "skin-edge")  # synth: targets for 'calibrate lights' and 'calibrate skin'
