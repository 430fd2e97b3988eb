"""Reference figures for tests/lbfgs.rs: SciPy L-BFGS-B on Rosenbrock-100.

Run once with `python3 optim/tests/scipy_rosenbrock100.py`; the printed numbers
are recorded as literals in tests/lbfgs.rs (the Rust tests never call Python).
x0 = [-1.2, 1, -1.2, 1, ...]; "reached" = first iterate with max|x - 1| <= 1e-8,
counted in function evaluations (SciPy evaluates value and gradient together).
"""
import numpy as np
import scipy
from scipy.optimize import minimize, rosen, rosen_der

n = 100
x0 = np.tile([-1.2, 1.0], n // 2)
nfev = 0
reached = None


def fun(x):
    global nfev
    nfev += 1
    return rosen(x), rosen_der(x)


def callback(intermediate_result):
    global reached
    if reached is None and np.max(np.abs(intermediate_result.x - 1.0)) <= 1e-8:
        reached = nfev


res = minimize(fun, x0, jac=True, method="L-BFGS-B", callback=callback,
               options={"maxcor": 10, "gtol": 1e-10, "ftol": 0.0,
                        "maxiter": 10000, "maxfun": 100000})
print("scipy", scipy.__version__)
print("message", res.message)
print("nfev", res.nfev, "nit", res.nit, "fun", res.fun,
      "max_err", np.max(np.abs(res.x - 1.0)))
print("nfev_to_1e-8", reached)
