# The two set-up commands (see README): `make demo` and `make test`.
PYTHON ?= python3
VENV ?= .venv
# Debian packages: libgl1/libgomp1 for the OpenCV and Open3D wheels, libusb for Open3D,
# chromium for the HTML-report browser test.
BASE_DEBS := libgl1 libgomp1
TEST_DEBS := $(BASE_DEBS) libusb-1.0-0 chromium
TEST_EXTRAS := test,dense,viz,ray,ros

# The portable check (issue 29): the compiled-kernel tests, the pinned figures and the determinism
# test again on a simulated second machine: another OpenBLAS kernel, numba code for a generic x86-64
# (no AVX2/FMA; its own cache), one OpenMP thread. `make test` runs it after the whole suite.
PORTABLE_ENV := OPENBLAS_CORETYPE=SandyBridge NUMBA_CPU_NAME=generic NUMBA_CACHE_DIR=$(CURDIR)/.numba-generic OMP_NUM_THREADS=1
# pytest-xdist processes for the suite and the portable check. On the 2-core CI machine, warm
# numba cache (2026-11-27): suite 8.4 min in one process, 5.2 with 2 (by file, so that a module's
# fixtures run once; 5.4 test by test); portable check 2.2 -> 1.0 min (test by test: its pinned
# rows spread over both; 1.4 by file). `make test TEST_WORKERS=0` runs everything in one process.
TEST_WORKERS ?= 2
PORTABLE_TESTS := $(sort $(wildcard tests/*/test_*kernels*.py)) tests/backend/test_schur_sparse.py tests/test_pinned_figures.py tests/test_determinism.py

.PHONY: demo test test-suite test-portable install install-test clean

$(VENV)/.installed: pyproject.toml constraints.txt scripts/bootstrap.sh
	bash scripts/bootstrap.sh "$(PYTHON)" "$(VENV)" "" $(BASE_DEBS)
	touch $@

$(VENV)/.installed-test: pyproject.toml constraints.txt scripts/bootstrap.sh
	bash scripts/bootstrap.sh "$(PYTHON)" "$(VENV)" "$(TEST_EXTRAS)" $(TEST_DEBS)
	touch $@ $(VENV)/.installed

install: $(VENV)/.installed
install-test: $(VENV)/.installed-test

demo: $(VENV)/.installed
	$(VENV)/bin/vslam demo --output demo_output

test: test-suite test-portable

test-suite: $(VENV)/.installed-test
	$(VENV)/bin/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile --durations=10

test-portable: $(VENV)/.installed-test
	$(PORTABLE_ENV) $(VENV)/bin/python -m pytest -q -p no:cacheprovider -n $(TEST_WORKERS) --dist load $(PORTABLE_TESTS)

clean:
	rm -rf $(VENV) demo_output .numba-generic
