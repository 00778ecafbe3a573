"""abyssal.runtime: NumPy/SciPy numerics on top of the compiled generated code."""
from .resampling import kld_sample_size
from .filters.kalman import CKF, EKF, MCUKF, UKF, FilterResult, HuberUKF, KalmanFilter, process_noise, repair_covariance

__all__ = [
    "CKF", "EKF", "FilterResult", "HuberUKF", "KalmanFilter", "MCUKF", "UKF", "kld_sample_size", "process_noise", "repair_covariance",
]
