"""Batched calls of generated C over particles and mixture components (see batches.py)."""
from .batches import (CubaturePredictBatch, CubatureStepBatch, CubatureUpdateBatch, MeasureBatch, ModelBatch, ParallelBatch,
                      nearest_positive_definite)

__all__ = ["CubaturePredictBatch", "CubatureStepBatch", "CubatureUpdateBatch", "MeasureBatch", "ModelBatch", "ParallelBatch",
           "nearest_positive_definite"]
