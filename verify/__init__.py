"""`abyssal verify`: every generated function against reference numerics it was not produced by.

It checks all three layers (symbolic, generated, runtime), so it sits above them: it imports them,
none of them imports it.

    driver.py             SECTIONS, the targets (built-ins, model folders, Models), run_all, verify_targets
    report.py             Check (one comparison, or a skip with its reason) and Report (table, JSON)
    models.py             model functions vs CasADi, the NumPy twin, central differences, solve_ivp, batches
    filters.py            filter steps vs filterpy and the exact Kalman filter
    remus.py tan.py cn.py the sections of the papers' models (GP export, fuzzy logic and maps, batches)
    reference_models.py   the independent NumPy models of the built-ins

The public entry point is the function ``abyssal.verify(target)``; it keeps that attribute of the
package ``abyssal``, so reach these modules with ``from abyssal.verify import driver`` (not
``import abyssal.verify.driver as ...``).
"""
