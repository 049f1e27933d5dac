"""Test-session settings shared by every test file.

Under pytest-xdist (README's test command: ``-n auto``, one worker per CPU) each worker keeps
to one BLAS / OpenMP thread, unless the environment says otherwise: with two workers on two
CPUs, numpy's thread pools (and Open3D's in its peer tests) would otherwise contend for the
same cores. xdist sets ``PYTEST_XDIST_WORKER_COUNT`` before a worker loads this file, and no
numpy is imported by then."""

import os

if os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1") != "1":
    for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(_var, "1")
