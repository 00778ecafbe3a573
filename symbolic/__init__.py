"""abyssal.symbolic: CasADi-only layer. Models, Fossen building blocks, discretisations,
filter algebra and code generation. Imports nothing from the numeric runtime."""
from .model import Model, Parameter, Quantity
from .models import REGISTRY

__all__ = ["Model", "Parameter", "Quantity", "REGISTRY"]
