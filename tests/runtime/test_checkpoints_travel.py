"""Checkpoints that travel (issue 33): a filter's checkpoint carries its kind, model (name and id), sizes and options;
it pickles and restores bit for bit in another process; a checkpoint of another kind, model, size or option set is
refused naming what differs, and the filter's memory (the C object the runtime writes) is never detached; a particle
filter's restore checks the cloud (N, finite particles, weights finite and summing to 1)."""
from __future__ import annotations

import pickle
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from abyssal.runtime.contract import CHECKPOINT_HEADER

MAKE = """
import numpy as np
import abyssal
from abyssal.runtime.filters.kalman import CKF, EKF, UKF
from abyssal.runtime.filters.particle import ParticleFilter
from abyssal.runtime.noise import GaussianMixture


def make(kind, name="rov4dof", **options):
    model = abyssal.load(name)
    n, m = model.n_x, model.n_y
    if kind == "PF":
        return ParticleFilter(model, np.zeros(n), 0.1 * np.eye(n), GaussianMixture.gaussian(np.zeros(n), 1e-4 * np.eye(n)),
                              GaussianMixture.gaussian(np.zeros(m), 0.1 * np.eye(m)), 64, 7)
    return {"CKF": CKF, "EKF": EKF, "UKF": UKF}[kind](model, np.zeros(n), 0.1 * np.eye(n), 1e-4 * np.eye(n),
                                                      0.1 * np.eye(m), **options)


def drive(flt, steps, start):
    model, out = flt.model, []
    for k in range(start, start + steps):
        u = 0.1 * np.sin(0.3 * k + np.arange(model.n_u))
        z = 0.05 * np.cos(0.2 * k + np.arange(model.n_y))
        flt.step(u, 0.1, z)
        out.append(np.concatenate([flt.x, flt.P.ravel()]))
    return np.array(out)
"""
namespace: dict = {}
exec(compile(MAKE, "<checkpoint helpers>", "exec"), namespace)
make, drive = namespace["make"], namespace["drive"]

WRITER = MAKE + """
import pickle, sys
kind, path = sys.argv[1], sys.argv[2]
flt = make(kind)
drive(flt, 25, 0)
saved = flt.checkpoint()
after = drive(flt, 15, 25)
with open(path, "wb") as stream:
    pickle.dump((saved, after), stream)
"""


@pytest.mark.timeout(300)
@pytest.mark.parametrize("kind", ["CKF", "EKF", "UKF", "PF"])
def test_a_checkpoint_pickled_in_another_process_restores_bit_for_bit(kind, tmp_path):
    path = tmp_path / "checkpoint.pickle"
    subprocess.run([sys.executable, "-c", textwrap.dedent(WRITER), kind, str(path)], check=True, timeout=240)
    saved, after = pickle.loads(path.read_bytes())
    assert saved[CHECKPOINT_HEADER]["kind"] == ("ParticleFilter" if kind == "PF" else kind)
    assert saved[CHECKPOINT_HEADER]["model"] == "rov4dof" and saved[CHECKPOINT_HEADER]["model id"]
    flt = make(kind)
    drive(flt, 3, 100)  # somewhere else entirely
    flt.restore(saved)
    assert np.array_equal(drive(flt, 15, 25), after)  # the same 15 steps, bit for bit, in this process


def refusal(flt, checkpoint) -> str:
    before = (flt.x, flt.P)
    with pytest.raises(ValueError, match="refused") as info:
        flt.restore(checkpoint)
    assert np.array_equal(flt.x, before[0]) and np.array_equal(flt.P, before[1])
    return str(info.value)


def test_another_kind_model_size_or_option_set_is_refused_naming_what_differs_and_memory_stays_attached():
    ckf = make("CKF")
    drive(ckf, 5, 0)
    own = ckf.checkpoint()
    ukf, ekf = make("UKF"), make("EKF")
    assert "kind 'CKF' (this filter: 'UKF')" in refusal(ukf, ckf.checkpoint())
    assert "kind 'CKF' (this filter: 'EKF')" in refusal(ekf, ckf.checkpoint())
    other_model = make("CKF", "linear_cv")
    message = refusal(other_model, ckf.checkpoint())
    assert "model 'rov4dof' (this filter: 'linear_cv')" in message and "model id" in message and "size n_x" in message
    gated = make("CKF", gate_probability=1e-3)
    assert "option gate_probability" in refusal(gated, ckf.checkpoint())
    assert "not a checkpoint of a filter" in refusal(ckf, {"_committed": np.zeros(3)})
    # after every refusal the filters still run on their own memory: their own checkpoints restore and change them
    for flt in (ckf, ukf, ekf, other_model, gated):
        assert np.shares_memory(flt._committed, flt._memory)
    drive(ckf, 4, 5)
    moved = ckf.x
    ckf.restore(own)
    assert not np.array_equal(ckf.x, moved) and np.shares_memory(ckf._committed, ckf._memory)
    drive(ckf, 4, 5)
    assert np.array_equal(ckf.x, moved)


def test_a_particle_filters_restore_checks_the_cloud():
    pf = make("PF")
    drive(pf, 3, 0)
    good = pf.checkpoint()

    def bad(**change):
        checkpoint = pickle.loads(pickle.dumps(good))
        checkpoint.update(change)
        return checkpoint

    assert "the weights must be finite, non-negative and sum to 1 (sum 3.0" in refusal(pf, bad(weights=3 * good["weights"]))
    nan = good["particles"].copy()
    nan[2, 5] = np.nan
    assert "particle 5 is not finite" in refusal(pf, bad(particles=nan))
    assert "N = 0 is not a particle count" in refusal(pf, bad(N=0))
    assert "shapes of particles" in refusal(pf, bad(N=10))
    assert "kind 'CKF' (this filter: 'ParticleFilter')" in refusal(pf, make("CKF").checkpoint())
    pf.restore(good)  # and its own restores
