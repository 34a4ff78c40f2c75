"""The solver's photometric model: the registry's model bound to the files its settings name.

A model that declares ``files`` (settings key -> file kind, e.g. Hapke's
``HAPKE_PARAMETERS`` PVL and ``HAPKE_PARAMETER_MAP`` cube) is configured here: the files
are read with the reader of their kind (ISIS adapters in :mod:`lunaralbedo.isis`), once per
process while they are unchanged (size and modification time), and handed to the model's
``configure``.  Models without files are used as is.
Used by the tile work, the scene check and the forward model.
"""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Any, Mapping

from ..errors import IsisError, SettingsError
from ..isis.parameter_map import read_parameter_map
from ..isis.pvlfile import read_object
from ..model import photometry
from ..model.photometry import PhotometricModel

#: File kinds a model may name in ``PhotometricModel.files`` -> reader (path -> contents).
READERS = {
    "photometric-pvl": lambda path: read_object(path, "PhotometricModel"),
    "parameter-map": read_parameter_map,
}


def bind(model: PhotometricModel, values: Mapping[str, Any], where: str = "settings") -> PhotometricModel:
    """``model`` bound to its settings ``values`` (legacy KEY -> value; files read once per process)."""
    if model.configure is None:
        return model
    stamps = tuple(_stamp(values.get(k)) for k in model.files)
    return _bound(model.name, tuple((k, values.get(k)) for k in model.settings), where, stamps)


def solver_model(settings) -> PhotometricModel:
    """The model of ``settings`` bound to its files; :class:`SettingsError` naming a bad file."""
    model = settings.model
    values = {key: getattr(settings, key.lower()) for key in model.settings}
    return bind(model, values, str(settings.source or "settings"))


def _stamp(path) -> tuple | None:
    try:
        st = Path(path).stat()
    except (TypeError, OSError):
        return None
    return st.st_size, st.st_mtime_ns


@lru_cache(maxsize=4)
def _bound(name: str, values: tuple, where: str, stamps: tuple) -> PhotometricModel:
    model, values = photometry.get(name), dict(values)
    contents = {}
    for key, kind in model.files.items():
        if values.get(key) is not None:
            try:
                contents[key] = READERS[kind](str(values[key]))
            except (IsisError, OSError) as exc:
                raise SettingsError(f"{key}: {exc}") from None
    return model.configure(values, contents, where)

