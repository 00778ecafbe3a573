"""abyssal.symbolic: CasADi-only layer. Models, Fossen building blocks, discretisations,
filter algebra and code generation. Imports nothing from the numeric runtime."""
from . import discretise, fossen
from .model import Model, Parameter, Quantity, symbols
from .models import REGISTRY

__all__ = ["Model", "Parameter", "Quantity", "REGISTRY", "discretise", "fossen", "symbols"]
