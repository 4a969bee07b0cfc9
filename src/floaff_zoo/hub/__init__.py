"""Checkpoint hub: resolve a hub name / checkpoint file / exported directory to weights and a model.

Offline first and sha256-verified; see :mod:`floaff_zoo.hub.io` for the resolution order and
:mod:`floaff_zoo.hub.registry` for the index format.
"""

from floaff_zoo.hub.io import fetch, import_model_class, load_model, read_weights, resolve_state_dict
from floaff_zoo.hub.registry import (
    ChecksumError,
    HubEntry,
    HubError,
    RegistryFormatError,
    RetiredEntryError,
    UnknownWeightsError,
    WeightsNotFoundError,
    get_entry,
    hub_dir,
    is_offline,
    load_registry,
    register,
    sha256_file,
)

__all__ = [
    "ChecksumError",
    "HubEntry",
    "HubError",
    "RegistryFormatError",
    "RetiredEntryError",
    "UnknownWeightsError",
    "WeightsNotFoundError",
    "fetch",
    "get_entry",
    "hub_dir",
    "import_model_class",
    "is_offline",
    "load_model",
    "load_registry",
    "read_weights",
    "register",
    "resolve_state_dict",
    "sha256_file",
]
