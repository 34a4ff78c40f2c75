"""Settings: the legacy PhotometryTK settings file (the PhotometryTK manual, section 5) or TOML.

Two spellings of the same settings are accepted:

* the legacy text file: one ``KEY value`` per line, ``#`` comments, free
  spacing, empty values allowed (e.g. no DEM in mosaic mode) and
  ``SIMULATION_BOX lon_min:lon_max:lat_min:lat_max`` with or without spaces
  (a box across ±180° may be written ``170:190`` or ``170:-170``; both are kept as
  the continuous longitudes 170..190);
* a ``.toml`` file with the same keys in snake_case.

Relative paths resolve against the folder of the settings file.  Unknown keys
and invalid values raise :class:`~lunaralbedo.errors.SettingsError` naming the
key and the allowed values.

The reflectance model is named by ``REFLECTANCE_TYPE`` (a legacy code) or, in TOML,
``reflectance = "<name>"`` (see :mod:`lunaralbedo.model.photometry`).  Settings a
model declares (e.g. PHASE_COEFF_C1/C2 of Lunar-Lambert) are accepted keys whatever
the model; the chosen model validates them.  This module knows no model by name.
"""
from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .errors import SettingsError
from .model import photometry
from .model.longitude import box_longitudes

#: (legacy key, type, default, allowed values or None); model-declared keys follow TR_CONST.
_CORE: dict[str, tuple[type, Any, tuple | None]] = {
    "DRG_DIR": (Path, None, None),
    "DEM_DIR": (Path, None, None),
    "SUN_POSITION_FILE": (Path, None, None),
    "SPACECRAFT_POSITION_FILE": (Path, None, None),
    "NUM_PROCESSES": (int, 1, None),
    "TILE_SIZE": (float, 4.0, None),
    "SIMULATION_BOX": (tuple, (-180.0, 180.0, -90.0, 90.0), None),
    "REFLECTANCE_TYPE": (int, photometry.get("lunar-lambert").code, None),  # allowed: the registry's codes (_spec)
    "SHADOW_THRESH": (float, 40.0, None),
    "SHADOW_TYPE": (int, 1, (0, 1, 2, 3)),
    "TR_CONST": (float, 1.5, None),
    "MAX_NUM_ITER": (int, 10, None),
    "NO_DEM_DATA_VAL": (float, -32767.0, None),
    "USE_WEIGHTS": (int, 1, (0, 1)),
    "USE_NORMALIZED_COST_FUN": (int, 0, (0, 1)),
    "COMPUTE_ERRORS": (int, 1, (0, 1)),
    "CAST_SHADOWS": (int, None, (0, 1)),  # None: on whenever the model uses a DEM
    "REFLECTANCE": (str, None, None),  # the model by name (TOML); wins over REFLECTANCE_TYPE; allowed: the registry's names
    "REGISTER_IMAGES": (int, 0, (0, 1)),  # 1: a ground shift per image found with the albedo (engine/registration.py)
    "REGISTER_MAX_SHIFT": (float, 5.0, None),  # the largest shift searched, pixels of each image
    # real images (docs/solver.md "Real images"): outliers, haze, exposures in physical units; not read by --legacy
    "REJECT_OUTLIERS": (int, 1, (0, 1)),  # each image's observations that stand out from their neighbourhood
    "ROBUST_LOSS": (str, "cauchy", ("cauchy", "huber", "none")),  # IRLS loss where >= 3 images overlap
    "ROBUST_THRESHOLD": (float, 5.0, None),  # k: the loss's scale in robust standard deviations (MAD)
    "FLOAT_HAZE": (int, 0, (0, 1)),  # per-image additive haze I = T A R + H
    "EXPOSURE_MODE": (str, "solve", ("solve", "fixed", "prior")),
    "EXPOSURE_FILE": (Path, None, None),  # key,exposure CSV for EXPOSURE_MODE fixed/prior
    "EXPOSURE_PRIOR_SIGMA": (float, 0.02, None),  # relative standard deviation of the exposure prior
    # shape from shading (docs/sfs.md): the DEM's heights refined with the albedo
    "REFINE_DEM": (int, 0, (0, 1)),
    "REFINE_DEM_ROUNDS": (int, 1, None),  # outer rounds: albedo solve, then heights, then albedo again
    "REFINE_DEM_SMOOTHNESS": (float, 0.003, None),  # mu, on the change of slope between pixels
    "REFINE_DEM_FIDELITY": (float, 1.0, None),  # lambda, on the refined heights smoothed to the input's resolution
    "REFINE_DEM_INPUT_BLUR": (float, "auto", None),  # sigma (pixels) of the input DEM's resolution; auto: estimated
    "REFINE_DEM_MARGIN": (int, 16, None),  # pixels of overlap around each window's heights
    "REFINE_DEM_WINDOW": (int, 256, None),  # most pixels a side of a height window (tiles are cut into such)
    "REFINE_DEM_LEVELS": (int, 2, None),  # coarse to fine: levels of a factor 2
    "REFINE_DEM_MAX_ITER": (int, 30, None),  # L-BFGS iterations per level and tile
    "REFINE_DEM_FLOAT_ALBEDO": (int, 1, (0, 1)),  # the albedo floats with the heights (per pixel least squares)
}


#: Keys of the default solver only (real images, shape from shading): :func:`legacy_text` leaves them out at their
#: defaults, so that a settings file does not pin today's defaults.
_UNWRITTEN_DEFAULTS = ("REJECT_OUTLIERS", "ROBUST_LOSS", "ROBUST_THRESHOLD", "FLOAT_HAZE", "EXPOSURE_MODE", "EXPOSURE_FILE",
                       "EXPOSURE_PRIOR_SIGMA", "REFINE_DEM", "REFINE_DEM_ROUNDS", "REFINE_DEM_SMOOTHNESS",
                       "REFINE_DEM_FIDELITY", "REFINE_DEM_INPUT_BLUR", "REFINE_DEM_MARGIN", "REFINE_DEM_WINDOW",
                       "REFINE_DEM_LEVELS", "REFINE_DEM_MAX_ITER", "REFINE_DEM_FLOAT_ALBEDO")


def _model_keys_spec() -> dict[str, tuple[type, Any, tuple | None]]:
    """Keys declared by the registered models (read at each call: a model registered later counts)."""
    return photometry.declared_settings()


def _spec() -> dict[str, tuple[type, Any, tuple | None]]:
    """Every key in the manual's order: the core keys, the models' keys after TR_CONST."""
    core = {**_CORE, "REFLECTANCE_TYPE": (*_CORE["REFLECTANCE_TYPE"][:2], tuple(photometry.codes())),
            "REFLECTANCE": (*_CORE["REFLECTANCE"][:2], tuple(photometry.names()))}
    at = list(core).index("TR_CONST") + 1
    return {**dict(list(core.items())[:at]), **_model_keys_spec(), **dict(list(core.items())[at:])}


@dataclass(frozen=True)
class Settings:
    """Validated settings of one albedo run (the PhotometryTK manual, section 5).

    Paths are absolute.  ``simulation_box`` is ``(lon_min, lon_max, lat_min,
    lat_max)`` in degrees; ``tile_size`` is in degrees.
    """

    drg_dir: Path
    dem_dir: Path | None = None
    sun_position_file: Path | None = None
    spacecraft_position_file: Path | None = None
    num_processes: int = 1
    tile_size: float = 4.0
    simulation_box: tuple[float, float, float, float] = (-180.0, 180.0, -90.0, 90.0)
    reflectance: str = "lunar-lambert"
    shadow_thresh: float = 40.0
    shadow_type: int = 1
    tr_const: float = 1.5
    max_num_iter: int = 10
    no_dem_data_val: float = -32767.0
    use_weights: int = 1
    use_normalized_cost_fun: int = 0
    compute_errors: int = 1
    cast_shadows: int | None = None
    register_images: int = 0
    register_max_shift: float = 5.0
    reject_outliers: int = 1
    robust_loss: str = "cauchy"
    robust_threshold: float = 5.0
    float_haze: int = 0
    exposure_mode: str = "solve"
    exposure_file: Path | None = None
    exposure_prior_sigma: float = 0.02
    refine_dem: int = 0
    refine_dem_rounds: int = 1
    refine_dem_smoothness: float = 0.003
    refine_dem_fidelity: float = 1.0
    refine_dem_input_blur: float | str = "auto"
    refine_dem_margin: int = 16
    refine_dem_window: int = 256
    refine_dem_levels: int = 2
    refine_dem_max_iter: int = 30
    refine_dem_float_albedo: int = 1
    #: Values of the model-declared keys, ``((LEGACY_KEY, value), ...)``; read as attributes (``s.phase_coeff_c1``).
    model_settings: tuple[tuple[str, Any], ...] = ()
    source: Path | None = field(default=None, compare=False)

    def __getattr__(self, name: str) -> Any:
        key = name.upper()
        declared = _model_keys_spec()
        if name.startswith("_") or key not in declared:
            raise AttributeError(name)
        return dict(self.__dict__.get("model_settings", ())).get(key, declared[key][1])

    @property
    def model(self) -> photometry.PhotometricModel:
        """The photometric model (:mod:`lunaralbedo.model.photometry`)."""
        return photometry.get(self.reflectance)

    @property
    def reflectance_type(self) -> int | None:
        """The legacy REFLECTANCE_TYPE code of the model (None if it has none)."""
        return self.model.code

    @property
    def initial_params(self):
        """Initial values of the model's fitted parameters (float64 array)."""
        return self.model.initial({key: getattr(self, key.lower()) for key in _model_keys_spec()})

    @property
    def needs_geometry(self) -> bool:
        """True when a DEM and Sun/spacecraft positions are required."""
        return self.model.needs_geometry

    @property
    def uses_cast_shadows(self) -> bool:
        """Cast shadows from the DEM: CAST_SHADOWS when given, else on whenever a DEM is used."""
        if not self.needs_geometry:
            return False
        return bool(self.cast_shadows) if self.cast_shadows is not None else True

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly echo (paths as strings); model-declared keys in snake_case like the others."""
        def plain(v):
            return str(v) if isinstance(v, Path) else (list(v) if isinstance(v, tuple) else v)

        out = {}
        for f in dataclasses.fields(self):
            if f.name == "model_settings":
                out.update({k.lower(): plain(getattr(self, k.lower())) for k in _model_keys_spec()})
                continue
            out[f.name] = plain(getattr(self, f.name))
        return out

    def to_legacy_text(self) -> str:
        """Render as a legacy settings file (absolute paths)."""
        values = {key: getattr(self, key.lower()) for key in _spec() if key not in ("REFLECTANCE_TYPE", "REFLECTANCE")}
        return legacy_text({**values, **model_entry(self.model)})


def model_entry(model) -> dict[str, Any]:
    """REFLECTANCE_TYPE when the model has a legacy code, else REFLECTANCE (its name)."""
    return {"REFLECTANCE_TYPE": model.code} if model.code is not None else {"REFLECTANCE": model.name}


def legacy_text(values: dict[str, Any], comment: str = "") -> str:
    """A legacy settings file with every key in the manual's order.

    ``values`` maps legacy keys to values (paths as given, e.g. relative); missing
    keys get their defaults, None an empty value.  ``comment`` lines are prefixed
    with ``#``.
    """
    spec = _spec()
    unknown = set(values) - set(spec)
    if unknown:
        raise SettingsError(f"unknown settings keys: {', '.join(sorted(unknown))}")
    lines = [f"# {c}" for c in comment.splitlines()]
    for key, (_typ, default, _allowed) in spec.items():
        if key == "REFLECTANCE" and values.get(key) is None:
            continue  # a model with a legacy code is written as REFLECTANCE_TYPE
        v = values.get(key, default)
        if key in _UNWRITTEN_DEFAULTS and v == default:
            continue  # not PhotometryTK's: written only when set, so the file stays readable by older readers
        if v is None:
            v = ""
        elif key == "SIMULATION_BOX":
            v = ":".join(f"{float(x):.10g}" for x in v)
        elif isinstance(v, float):
            v = f"{v:.10g}"
        lines.append(f"{key:<26}{v}".rstrip())
    return "\n".join(lines) + "\n"


def _parse_box(text: str, where: str) -> tuple[float, float, float, float]:
    parts = [p.strip() for p in str(text).split(":")]
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        vals = ()
    if len(vals) != 4:
        raise SettingsError(
            f"{where}: SIMULATION_BOX must be lon_min:lon_max:lat_min:lat_max (4 numbers), got {text!r}"
        )
    lon0, lon1, lat0, lat1 = vals
    lon0, lon1 = box_longitudes(lon0, lon1)  # 170:-170 crosses the antimeridian: 170..190
    if not (lon0 < lon1 and lat0 < lat1):
        raise SettingsError(f"{where}: SIMULATION_BOX needs lon_min < lon_max and lat_min < lat_max, got {text!r}")
    if lon1 - lon0 > 360.0 + 1e-9:
        raise SettingsError(f"{where}: SIMULATION_BOX spans more than 360 degrees of longitude, got {text!r}")
    # The legacy sample used -180:180:-180:180 for "the whole Moon": clamp latitudes.
    return (lon0, lon1, max(lat0, -90.0), min(lat1, 90.0))


#: Numeric keys that also take the word ``auto`` (estimated by the run).
_AUTO_KEYS = ("REFINE_DEM_INPUT_BLUR",)


def _convert(key: str, raw: Any, base: Path, where: str, spec: dict) -> Any:
    typ, _default, allowed = spec[key]
    if raw is None or (isinstance(raw, str) and raw.strip() == ""):
        return None
    if typ is Path:
        p = Path(str(raw)).expanduser()
        return p if p.is_absolute() else (base / p)
    if typ is tuple:
        if isinstance(raw, (list, tuple)):
            raw = ":".join(str(x) for x in raw)
        return _parse_box(raw, where)
    if key in _AUTO_KEYS and str(raw).strip().lower() == "auto":
        return "auto"
    if typ is str:
        if str(raw) not in allowed:
            raise SettingsError(f"{where}: {key} must be one of {', '.join(allowed)}, got {raw!r}")
        return str(raw)
    try:
        if typ is int:
            fv = float(raw)
            if fv != int(fv):
                raise ValueError
            val = int(fv)
        else:
            val = float(raw)
    except (TypeError, ValueError):
        hint = f"one of {', '.join(map(str, allowed))}" if allowed else f"a {typ.__name__}"
        hint += " or auto" if key in _AUTO_KEYS else ""
        raise SettingsError(f"{where}: {key} must be {hint}, got {raw!r}") from None
    if allowed is not None and val not in allowed:
        raise SettingsError(f"{where}: {key} must be one of {', '.join(map(str, allowed))}, got {raw!r}")
    return val


def _validate(values: dict[str, Any], where: str) -> None:
    if values.get("DRG_DIR") is None:
        raise SettingsError(f"{where}: DRG_DIR is required")
    if values["TILE_SIZE"] <= 0:
        raise SettingsError(f"{where}: TILE_SIZE must be > 0 degrees, got {values['TILE_SIZE']}")
    if values["NUM_PROCESSES"] < 1:
        raise SettingsError(f"{where}: NUM_PROCESSES must be >= 1, got {values['NUM_PROCESSES']}")
    if values["MAX_NUM_ITER"] < 0:
        raise SettingsError(f"{where}: MAX_NUM_ITER must be >= 0, got {values['MAX_NUM_ITER']}")
    if not (0.0 <= values["REGISTER_MAX_SHIFT"] < float("inf")):
        raise SettingsError(f"{where}: REGISTER_MAX_SHIFT must be a number of pixels >= 0, got {values['REGISTER_MAX_SHIFT']}")
    for key in ("ROBUST_THRESHOLD", "EXPOSURE_PRIOR_SIGMA"):
        if not (math.isfinite(values[key]) and values[key] > 0):
            raise SettingsError(f"{where}: {key} must be a number > 0, got {values[key]}")
    model = photometry.get(values["REFLECTANCE"] or values["REFLECTANCE_TYPE"])
    if values["REGISTER_IMAGES"] and not model.needs_geometry:
        raise SettingsError(f"{where}: REGISTER_IMAGES 1 needs a DEM: the {model.name} model uses none")
    if model.needs_geometry:
        for key in ("DEM_DIR", "SUN_POSITION_FILE", "SPACECRAFT_POSITION_FILE"):
            if values.get(key) is None:
                raise SettingsError(
                    f"{where}: {key} is required by the {model.name} reflectance model "
                    "(only REFLECTANCE_TYPE 0, mosaic mode, runs without it)"
                )
    if model.validate is not None:
        model.validate(values, where)
    _validate_refine(values, where, model)


def _validate_refine(values: dict[str, Any], where: str, model) -> None:
    """The REFINE_DEM_* keys (docs/sfs.md)."""
    if values["REFINE_DEM"] and not model.needs_geometry:
        raise SettingsError(f"{where}: REFINE_DEM 1 needs a reflectance model with a DEM (not mosaic mode)")
    for key, lo in (("REFINE_DEM_ROUNDS", 1), ("REFINE_DEM_MARGIN", 4), ("REFINE_DEM_WINDOW", 16), ("REFINE_DEM_LEVELS", 1),
                    ("REFINE_DEM_MAX_ITER", 1)):
        if values[key] < lo:
            raise SettingsError(f"{where}: {key} must be >= {lo}, got {values[key]}")
    if values["REFINE_DEM_INPUT_BLUR"] is None:  # an empty value: estimated, as the default
        values["REFINE_DEM_INPUT_BLUR"] = "auto"
    for key in ("REFINE_DEM_SMOOTHNESS", "REFINE_DEM_FIDELITY", "REFINE_DEM_INPUT_BLUR"):
        if values[key] is None or values[key] == "auto" and key in _AUTO_KEYS:
            continue
        if not 0 <= values[key] < float("inf"):
            auto = " (or auto)" if key in _AUTO_KEYS else ""
            raise SettingsError(f"{where}: {key} must be a number >= 0{auto}, got {values[key]}")


def _build(pairs: list[tuple[str, Any, str]], base: Path, source: Path) -> Settings:
    spec = _spec()
    values: dict[str, Any] = {k: v[1] for k, v in spec.items()}
    seen: set[str] = set()
    for key, raw, where in pairs:
        if key not in spec:
            raise SettingsError(f"{where}: unknown key {key!r}; allowed keys: {', '.join(spec)}")
        if key in seen:
            raise SettingsError(f"{where}: key {key} is given twice")
        seen.add(key)
        conv = _convert(key, raw, base, where, spec)
        values[key] = conv if (conv is not None or spec[key][0] is Path) else spec[key][1]
    _validate(values, str(source))
    return _settings(values, source)


def _settings(values: dict[str, Any], source: Path | None) -> Settings:
    """A :class:`Settings` from validated values keyed by legacy key."""
    model = photometry.get(values["REFLECTANCE"] or values["REFLECTANCE_TYPE"])
    core = {k.lower(): v for k, v in values.items() if k in _CORE and k not in ("REFLECTANCE_TYPE", "REFLECTANCE")}
    return Settings(**core, reflectance=model.name, model_settings=tuple((k, values[k]) for k in _model_keys_spec()),
                    source=source)


def parse_legacy(text: str, source: Path) -> Settings:
    """Parse the text of a legacy settings file (the PhotometryTK manual, section 5 and appendix)."""
    pairs = []
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split(None, 1)
        key = parts[0].upper()
        raw = parts[1].strip() if len(parts) > 1 else ""
        pairs.append((key, raw, f"{source}:{lineno}"))
    return _build(pairs, source.parent, source)


def parse_toml(text: str, source: Path) -> Settings:
    """Parse a TOML settings file whose keys are the legacy ones in snake_case."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SettingsError(f"{source}: not valid TOML: {exc}") from None
    pairs = []
    for key, raw in data.items():
        if isinstance(raw, dict):
            raise SettingsError(f"{source}: tables are not allowed (key {key!r}); write settings at top level")
        pairs.append((key.upper(), raw, f"{source}: key {key!r}"))
    return _build(pairs, source.parent, source)


def load_settings(path: str | Path) -> Settings:
    """Read a legacy or TOML settings file (chosen by the ``.toml`` suffix)."""
    path = Path(path).expanduser().resolve()
    if not path.is_file():
        raise SettingsError(f"{path}: settings file not found")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise SettingsError(f"{path}: cannot read settings file: {exc}") from None
    if path.suffix.lower() == ".toml":
        return parse_toml(text, path)
    return parse_legacy(text, path)


def replace(settings: Settings, **changes: Any) -> Settings:
    """A copy of ``settings`` with some fields changed (no validation: pass valid values).

    Field names as attributes: model-declared keys (``phase_coeff_c1``) and
    ``reflectance_type`` (a legacy code) are accepted too.
    """
    if "reflectance_type" in changes:
        changes["reflectance"] = photometry.get(changes.pop("reflectance_type")).name
    declared = _model_keys_spec()
    model_changes = {k.upper(): changes.pop(k) for k in list(changes) if k.upper() in declared}
    if model_changes:
        merged = {**dict(settings.model_settings), **model_changes}
        changes["model_settings"] = tuple((k, merged.get(k, declared[k][1])) for k in declared)
    return dataclasses.replace(settings, **changes)
