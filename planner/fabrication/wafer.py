"""Where a die sat on its wafer: the die grid and the wafer's spatially correlated
line-width errors (``fabrication.wafer``, issue 39).

Without ``fabrication.wafer`` every chip of a yield study is a die of its own: its
die-level errors are drawn independently (:func:`planner.fabrication.tolerances.sample_chip`).  A
fab's wafer is not like that: across it the line width drifts smoothly and by a lot,
while inside a small region it barely changes (MKID resonator arrays: ~1.5 % smooth
deviation across the wafer against 0.27 % local scatter, McKenney et al. 2019), so
neighbouring dies are alike; and inside one die a line-width gradient makes far devices
differ more than near ones.  With ``fabrication.wafer`` a yield study's chips are the
dies of wafers:

- **the die grid** (:func:`wafer_layout`): dies of ``die_size_mm`` (default the array's
  cols x pitch by rows x pitch) on a grid centred on the wafer, every die whose four
  corners lie within ``diameter_mm / 2 - edge_exclusion_mm`` of the centre; each die is
  named by its grid indices ``(die_x, die_y)`` (x along the array's columns, y up, the
  centre die (0, 0)), and the dies are taken in reading order (top row first, left to
  right);
- **the across-wafer field**: a Gaussian random field of the line width at the die
  centres, covariance sigma^2 exp(-r^2 / (2 L^2)) (squared exponential), drawn through
  the Cholesky factor of that covariance: one value per die, added to every device of it;
- **the within-die gradient**: per die, a linear line-width gradient (g_x, g_y), each
  component normal with sigma ``line_width_gradient_um_per_mm``; a device at (x, y)
  from its die's centre gets g_x x + g_y y.

Both come on top of the die, device and pair levels of ``line_width_um``, which every
die still draws from its own chip seed: die ``k`` of wafer ``w`` is chip
``w * dies_per_wafer + k`` of the study and draws exactly what that chip draws without
a wafer, plus the wafer's part (from :func:`wafer_seed`, a stream of its own).

Units: positions are SI [m] inside, the user's keys are in mm; line-width errors are
in um, the unit of :data:`planner.fabrication.tolerances.ERRORS`.
"""

from __future__ import annotations

import functools
import math
import struct
from dataclasses import dataclass

import numpy as np

from planner.core.nodes import device_key
from planner.core.units import MM, UM

#: The stream tag of a wafer's draws (its field and gradients), apart from every chip's.
WAFER_STREAM = 39
#: Most dies on one wafer: the field's covariance is dies x dies (128 MB at this size)
#: and its Cholesky factor takes a few seconds.
MAX_DIES = 4000
#: Relative jitter added to the field's correlation matrix when its Cholesky fails (a
#: squared-exponential correlation of closely spaced dies is numerically singular): the
#: smallest of these that factors it; 1e-6 changes the field by ~1e-3 of its sigma.
JITTERS = (0.0, 1e-12, 1e-10, 1e-8, 1e-6)


@dataclass(frozen=True)
class WaferLayout:
    """The dies of one wafer.

    Attributes
    ----------
    die_x, die_y : ndarray of int, shape (n_dies,)
        Grid indices of each die (the centre die is (0, 0); y up), reading order.
    x, y : ndarray, shape (n_dies,)
        Die centres from the wafer's centre [m].
    die_size : (float, float)
        Die width and height [m].
    radius : float
        The wafer's radius [m].
    usable_radius : float
        The radius inside the edge exclusion [m].
    """

    die_x: np.ndarray
    die_y: np.ndarray
    x: np.ndarray
    y: np.ndarray
    die_size: tuple
    radius: float
    usable_radius: float

    @property
    def count(self) -> int:
        return int(self.die_x.size)

    @property
    def die_radius(self) -> np.ndarray:
        """Distance of every die's centre from the wafer's centre [m]."""
        return np.hypot(self.x, self.y)


def die_size(array, wafer) -> tuple[float, float]:
    """A die's width and height [m]: ``wafer.die_size_mm``, else the array's cols x pitch
    by rows x pitch (``array`` an :class:`~planner.arrayspec.schema.ArrayConfig`)."""
    if wafer.die_size_mm is not None:
        return wafer.die_size_mm[0] * MM, wafer.die_size_mm[1] * MM
    return array.cols * array.pitch_um * UM, array.rows * array.pitch_um * UM


@functools.lru_cache(maxsize=16)
def wafer_layout(array, wafer) -> WaferLayout:
    """The dies of a wafer ``wafer`` (:class:`~planner.arrayspec.WaferSpec`) of dies holding
    ``array`` (the spec's :class:`~planner.arrayspec.schema.ArrayConfig`).

    Raises
    ------
    ValueError
        The die is smaller than the array it holds, no die fits inside the edge
        exclusion, or more than :data:`MAX_DIES` do; naming the field.

    Examples
    --------
    >>> from planner.arrayspec import ArraySpec, WaferSpec
    >>> spec = ArraySpec.model_validate({"array": {"rows": 5, "cols": 5, "pitch_um": 2000.0}})
    >>> wafer_layout(spec.array, WaferSpec(diameter_mm=100.0)).count
    49
    """
    w, h = die_size(array, wafer)
    # the array takes cols x pitch by rows x pitch (each device a pitch square, the
    # default die): a smaller die cannot hold it
    need_w, need_h = array.cols * array.pitch_um * UM, array.rows * array.pitch_um * UM
    if wafer.die_size_mm is not None and (w < need_w * (1 - 1e-12)
                                          or h < need_h * (1 - 1e-12)):
        raise ValueError(f"fabrication.wafer.die_size_mm: {list(wafer.die_size_mm)} mm cannot "
                         f"hold the {array.rows} x {array.cols} array at a pitch of "
                         f"{array.pitch_um:g} um ({need_w / MM:g} x {need_h / MM:g} mm)")
    radius = 0.5 * wafer.diameter_mm * MM
    usable = radius - wafer.edge_exclusion_mm * MM
    # counted before the grid is built: a die whose centre lies within usable - its
    # diagonal has its corners inside, so at least pi (usable - diagonal)^2 / (w h) dies
    # are made (a 1e6 mm wafer would otherwise build a grid of 1e11 candidates)
    inner = usable - math.hypot(w, h)
    at_least = math.pi * inner * inner / (w * h) if inner > 0 else 0.0
    if at_least > MAX_DIES:
        raise ValueError(f"fabrication.wafer.diameter_mm: {wafer.diameter_mm:g} mm holds more "
                         f"than {at_least:.3g} dies of {w / MM:g} x {h / MM:g} mm, at most "
                         f"{MAX_DIES} are supported (the across-wafer field's covariance "
                         "is dies x dies)")
    nx, ny = int(math.ceil(usable / w)) + 1, int(math.ceil(usable / h)) + 1
    ix, iy = np.meshgrid(np.arange(-nx, nx + 1), np.arange(-ny, ny + 1))
    ix, iy = ix.ravel(), iy.ravel()
    # a die is made when its farthest corner lies inside the usable radius
    far = np.hypot(np.abs(ix) * w + 0.5 * w, np.abs(iy) * h + 0.5 * h)
    keep = far <= usable * (1 + 1e-12)
    ix, iy = ix[keep], iy[keep]
    if ix.size == 0:
        raise ValueError(f"fabrication.wafer.diameter_mm: no {w / MM:g} x {h / MM:g} mm die "
                         f"fits a wafer of {wafer.diameter_mm:g} mm with "
                         f"{wafer.edge_exclusion_mm:g} mm edge exclusion")
    if ix.size > MAX_DIES:
        raise ValueError(f"fabrication.wafer.diameter_mm: {ix.size} dies of {w / MM:g} x "
                         f"{h / MM:g} mm on one wafer, at most {MAX_DIES} are supported "
                         "(the across-wafer field's covariance is dies x dies)")
    order = np.lexsort((ix, -iy))           # reading order: top row first, left to right
    ix, iy = ix[order].astype(np.int64), iy[order].astype(np.int64)
    return WaferLayout(ix, iy, ix * w, iy * h, (w, h), radius, usable)


def device_positions(array) -> dict:
    """Device id -> its (x, y) from its die's centre [m]: the array centred in the die,
    row A at the top, column 1 on the left."""
    p = array.pitch_um * UM
    out = {}
    for d in array.device_ids():
        r, c = ord(d[0]) - ord("A"), int(d[1:]) - 1
        out[d] = ((c - 0.5 * (array.cols - 1)) * p, (0.5 * (array.rows - 1) - r) * p)
    return out


def wafer_seed(seed: int, scale: float, wafer: int) -> np.random.SeedSequence:
    """The seed sequence of wafer ``wafer`` of a yield study at sigma scale ``scale``:
    the run's seed, the scale's exact value and the wafer's index, and
    :data:`WAFER_STREAM`, so that no chip's stream
    (:func:`planner.core.rng.chip_seed`) is a wafer's."""
    bits = struct.unpack("<Q", struct.pack("<d", float(scale) + 0.0))[0]
    return np.random.SeedSequence([int(seed), int(bits), int(wafer), WAFER_STREAM])


def field_factor(x, y, correlation_length: float) -> np.ndarray:
    """The lower Cholesky factor of the squared-exponential correlation of points
    (x, y) [m], ``exp(-r^2 / (2 L^2))`` with L ``correlation_length`` [m], shape
    (n, n): the field at the points is sigma (factor @ z), z standard normal.

    The smallest jitter of :data:`JITTERS` (relative, on the diagonal) that lets it
    factor is added: points closer than a tenth of L make it numerically singular.
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    d2 = (x[:, None] - x[None, :]) ** 2 + (y[:, None] - y[None, :]) ** 2
    corr = np.exp(-0.5 * d2 / (correlation_length * correlation_length))
    for jitter in JITTERS:
        try:
            return np.linalg.cholesky(corr + jitter * np.eye(x.size))
        except np.linalg.LinAlgError:
            continue
    raise ValueError("fabrication.wafer.line_width_field: its correlation cannot be "
                     "factored (correlation_length_mm far larger than the wafer?)")


@functools.lru_cache(maxsize=4)
def _layout_factor(array, wafer) -> np.ndarray:
    """:func:`field_factor` of a wafer's dies: one Cholesky factor for every wafer of a
    study (the dies and the correlation length are the same; only the normals differ)."""
    layout = wafer_layout(array, wafer)
    return field_factor(layout.x, layout.y, wafer.line_width_field.correlation_length_mm * MM)


@functools.lru_cache(maxsize=16)
def wafer_draws(array, wafer, seed: int, scale: float, index: int):
    """The line-width errors of wafer ``index`` of a study: ``(field, gradient)``, the
    field at every die's centre [um], shape (n_dies,), and every die's gradient
    (g_x, g_y) [um/m], shape (n_dies, 2), dies in :func:`wafer_layout`'s order.

    Drawn from :func:`wafer_seed` in a fixed order whatever the sigmas (the field's
    normals, then the gradients'); cached, as every die of a wafer asks for them.
    """
    layout = wafer_layout(array, wafer)
    rng = np.random.default_rng(wafer_seed(seed, scale, index))
    z_field = rng.standard_normal(layout.count)
    z_grad = rng.standard_normal((layout.count, 2))
    f = wafer.line_width_field
    field = np.zeros(layout.count)
    if f.sigma_um > 0 and scale > 0:
        field = scale * f.sigma_um * (_layout_factor(array, wafer) @ z_field)
    grad = scale * wafer.line_width_gradient_um_per_mm / MM * z_grad
    return field, grad


def line_width_offsets(spec, fab, seed: int, scale: float, chip: int) -> dict | None:
    """Device id -> the line width [um] the wafer adds to that device of chip ``chip``
    (its die's field value plus the gradient at the device); None without
    ``fab.wafer`` or at scale 0 (the nominal chip): then nothing is added.

    Parameters
    ----------
    spec : ArraySpec
        The plan's spec (its array: the dies' size and the devices' places in them).
    fab : FabricationSpec
        The tolerance model in use (its ``wafer``).
    seed : int
        The study's seed.
    scale : float
        The sigma scale [-] (multiplies the field and the gradient).
    chip : int
        The chip's index in the study: die ``chip % dies`` of wafer ``chip // dies``.
    """
    if fab.wafer is None or scale == 0:
        return None
    n = wafer_layout(spec.array, fab.wafer).count
    field, grad = wafer_draws(spec.array, fab.wafer, int(seed), float(scale), int(chip) // n)
    k = int(chip) % n
    out = {}
    for d, (x, y) in sorted(device_positions(spec.array).items(),
                            key=lambda kv: device_key(kv[0])):
        out[d] = float(field[k]) + float(grad[k, 0]) * x + float(grad[k, 1]) * y
    return out


def die_place(array, wafer, chip: int) -> dict:
    """Where chip ``chip`` of a study sat: ``wafer`` (index, from 0), ``die_x``,
    ``die_y`` (grid indices), ``x_mm``, ``y_mm`` and ``radius_mm`` (its centre from the
    wafer's)."""
    layout = wafer_layout(array, wafer)
    k = int(chip) % layout.count
    return {"wafer": int(chip) // layout.count, "die_x": int(layout.die_x[k]),
            "die_y": int(layout.die_y[k]), "x_mm": float(layout.x[k] / MM),
            "y_mm": float(layout.y[k] / MM), "radius_mm": float(layout.die_radius[k] / MM)}
