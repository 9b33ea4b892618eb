# The two set-up commands (see README): `make demo` and `make test`.
PYTHON ?= python3
VENV ?= .venv
# Debian packages: libgl1/libgomp1 for the OpenCV and Open3D wheels, libusb for Open3D,
# chromium for the HTML-report browser test.
BASE_DEBS := libgl1 libgomp1
TEST_DEBS := $(BASE_DEBS) libusb-1.0-0 chromium
TEST_EXTRAS := test,dense,viz,ray,ros

.PHONY: demo test install install-test clean

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

test: $(VENV)/.installed-test
	$(VENV)/bin/python -m pytest -q --durations=10

clean:
	rm -rf $(VENV) demo_output
