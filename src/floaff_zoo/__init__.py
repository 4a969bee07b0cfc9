"""floaff-zoo: a PyTorch Lightning model zoo for Floor Affordance (FloAff) prediction."""

__version__ = "0.1.0"

__all__ = ["__version__"]
