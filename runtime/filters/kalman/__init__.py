"""Kalman-family filters running whole generated filter steps (see engine.py for the contract)."""
from .engine import CKF, EKF, MCUKF, UKF, FilterResult, HuberUKF, KalmanFilter, process_noise, repair_covariance
from .gp_ukf import GPUKF
from .ivbckf import IVBCKF

__all__ = ["CKF", "EKF", "FilterResult", "GPUKF", "HuberUKF", "IVBCKF", "KalmanFilter", "MCUKF", "UKF", "process_noise",
           "repair_covariance"]
