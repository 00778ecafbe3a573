import numpy as np
import abyssal.generated
from abyssal.runtime import CKF
rov, rng, dt = abyssal.generated.load("rov4dof"), np.random.default_rng(0), 0.1
Q, R = np.diag([1e-4] * 8 + [1e-2] * 4), np.diag([0.05, 0.05, 0.02, 0.01])
U = np.tile([20.0, 5.0, 10.0, 0.5], (300, 1))                     # thrust [X Y Z N] for 30 s
X = [np.zeros(12)]
for u in U:
    X.append(rov.f(X[-1], u, None, dt) + rng.multivariate_normal(np.zeros(12), Q))
Z = np.array([rov.h(x) for x in X[1:]]) + rng.multivariate_normal(np.zeros(4), R, size=len(U))
result = CKF(rov, np.zeros(12), 0.3 * np.eye(12), Q, R).run(U, Z, dt, truth=np.array(X[1:]))
print("RMSE x y z psi:", result.rmse(np.array(X[1:]))[:4].round(3), " mean NIS:", np.nanmean(result.nis).round(2))
