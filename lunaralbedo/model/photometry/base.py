r"""The interface every photometric model implements (see :mod:`lunaralbedo.model.photometry`).

A model is a :class:`PhotometricModel` value built by its own module.  The solver
never looks inside: it asks the model for

* ``layers(cos_i, cos_e, alpha, lon=None, lat=None)``: the per-observation arrays that
  do not depend on the fitted parameters (cached once per tile; float32 in the cache);
  ``lon``, ``lat`` (degrees) are the ground points, for models whose parameters vary
  over the ground (Hapke with a parameter map);
* ``reflectance_from(arrays, params)``: :math:`R` from those cached ``arrays`` (which
  also hold ``"image"``, the observed stack); keeps the arrays' dtype, so float32
  caches give float32 :math:`R`;
* ``derivatives_from(arrays, params)``: :math:`\partial R/\partial p_m` for every
  fitted parameter, same dtype (used by eq. 5);

and the forward model asks for ``reflectance(cos_i, cos_e, alpha, params)``
(float64).  A model that fits parameters should also give ``point`` (see
:mod:`.pointwise`): the numba form of :math:`R` and :math:`\partial R/\partial p_m` for one
observation, which the iterate kernel inlines; its NumPy functions are then built on the
same ``point`` (one implementation).  Models without it go through a generic path
(:math:`R` and its derivatives as NumPy arrays each iteration).  A model whose settings name files (``files``: settings key -> file kind) is
used *bound*: the engine reads those files (:mod:`lunaralbedo.engine.photometry`) and
``configure(values, contents, where)`` returns the model bound to them; the model itself
does no I/O.  Angles: :math:`\cos i`, :math:`\cos e` dimensionless, :math:`\alpha` in
radians.  A model that fits parameters must provide an ``"alpha"`` layer (the solver
takes the observed phase-angle range from it).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

#: One declared setting: (type, default, allowed values or None) -- the form of settings.py.
SettingSpec = tuple[type, Any, "tuple | None"]


@dataclass(frozen=True)
class PhotometricModel:
    """A reflectance model: its names, fitted parameters, declared settings and functions."""

    name: str  #: TOML ``reflectance = "<name>"``
    code: int | None  #: legacy ``REFLECTANCE_TYPE`` (None: no legacy code)
    description: str
    layers: Callable[..., dict[str, np.ndarray]]
    reflectance_from: Callable[[Mapping[str, np.ndarray], np.ndarray], np.ndarray]
    reflectance: Callable[..., np.ndarray]
    layer_names: tuple[str, ...] = ()  #: keys of ``layers(...)``
    parameters: tuple[str, ...] = ()  #: names of the fitted parameters (phase.csv columns, report keys)
    derivatives_from: Callable[[Mapping[str, np.ndarray], np.ndarray], tuple[np.ndarray, ...]] | None = None
    #: Settings keys the model declares (legacy KEY -> spec), in the settings file's order.
    settings: dict[str, SettingSpec] = field(default_factory=dict)
    #: Legacy keys holding the fitted parameters' initial values, in ``parameters`` order.
    initial_keys: tuple[str, ...] = ()
    #: ``validate(values, where)`` raises SettingsError for invalid model settings.
    validate: Callable[[Mapping[str, Any], str], None] | None = None
    needs_geometry: bool = True  #: needs a DEM and Sun/spacecraft positions
    #: ``layers`` uses the ground points' ``lon``/``lat`` (a parameter map); the engine passes them only then
    needs_location: bool = False
    #: ``curve(alpha, params)``: the parameter-dependent part of R against phase angle (radians),
    #: which caps the damped step; default: R at the symmetric geometry i = e = alpha/2.
    curve: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None
    #: Settings keys naming files the model needs, with the file's kind (``"photometric-pvl"``, ``"parameter-map"``).
    files: dict[str, str] = field(default_factory=dict)
    #: ``configure(values, contents, where)``: the model bound to its settings ``values`` (legacy KEY -> value)
    #: and the ``contents`` of its ``files`` (KEY -> what was read); None: usable as is.
    configure: Callable[..., "PhotometricModel"] | None = None
    #: Numba scalar form ``point(l0, l1, l2, params) -> (R, dR/dp_0, dR/dp_1)`` (:mod:`.pointwise`)
    #: of the layers ``point_layers``; None: the engine uses ``reflectance_from``/``derivatives_from``.
    point: Callable | None = None
    point_layers: tuple[str, ...] = ()
    #: The iterate kernel's branch that inlines ``point`` (:func:`lunaralbedo.engine.kernels._point` calls the
    #: model's ``point`` for this number; a numba function cannot be passed as an argument without compiling
    #: the kernel again in every process); 0: the kernel takes R and dR/dp as arrays.
    point_kind: int = 0
    #: Files a forward-model scene writes for this model: settings KEY -> (file name, text).
    examples: dict[str, tuple[str, str]] = field(default_factory=dict)

    def initial(self, values: Mapping[str, Any]) -> np.ndarray:
        """Initial fitted parameters (float64) from settings values keyed by legacy key."""
        return np.array([float(values[k]) for k in self.initial_keys], dtype=np.float64)

    def phase_curve(self, alpha, params) -> np.ndarray:
        """Reflectance against phase angle (radians): ``curve``, or R at the symmetric geometry."""
        if self.curve is not None:
            return self.curve(alpha, params)
        half = np.cos(np.asarray(alpha, dtype=np.float64) / 2.0)
        return self.reflectance(half, half, alpha, params)
