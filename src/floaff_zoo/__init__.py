"""floaff-zoo: a PyTorch Lightning model zoo for Floor Affordance (FloAff) prediction."""

from floaff_zoo._version import __version__

__all__ = ["__version__", "predict", "predict_from_points", "Prediction"]


def __getattr__(name: str):
    # Lazy: `import floaff_zoo` stays light (no torch/Lightning) until the predict API is used.
    if name in ("predict", "predict_from_points", "Prediction"):
        import importlib

        mod = importlib.import_module("floaff_zoo.predict")
        return mod if name == "predict" else getattr(mod, name)
    raise AttributeError(f"module 'floaff_zoo' has no attribute {name!r}")
