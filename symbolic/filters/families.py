"""The filter families, named once: which generated functions each provides.

symbolic/filters builds them under these names (prefixed with the model's name), regenerate picks
the families a model gets, verify checks them, and the runtime's Kalman classes and unscented
particle filters bind them.
"""

#: every filter family, in the order of the generated units
FAMILIES = ("ekf", "ukf", "ckf", "robust")
#: family -> families it builds on (the robust filters predict with the UKF step)
REQUIRES = {"robust": ("ukf",)}
#: family -> role -> generated function (without the model's prefix). "predict_points" (x, P -> the points) and
#: "predict_weights" (the points' weights) are the rule of a sigma-point predict for the C runtime of the Kalman
#: family, which propagates the points through the model's SIMD kernel <m>_f_soa and forms their moments.
FUNCTIONS = {
    "ekf": {"predict": "ekf_predict", "update": "ekf_update", "step": "ekf_step"},
    "ukf": {"predict": "ukf_predict", "update": "ukf_update", "predict_points": "ukf_predict_points",
            "predict_weights": "ukf_predict_weights"},
    "ckf": {"predict": "ckf_predict", "update": "ckf_update", "step": "ckf_step", "predict_points": "ckf_predict_points",
            "predict_weights": "ckf_predict_weights"},
    "robust": {"mcc_update": "mcukf_update", "huber_update": "huber_ukf_update"},
}
