"""abyssal.symbolic: CasADi-only layer. Models, Fossen building blocks, discretisations,
filter algebra and code generation. Imports nothing from the numeric runtime."""
from . import discretise, fossen
from .model import Envelope, Model, Parameter, Quantity, Sensor, symbols
from .models import REGISTRY

__all__ = ["Envelope", "Model", "Parameter", "Quantity", "REGISTRY", "Sensor", "discretise", "fossen", "symbols"]
