# The two commands of the README: `make demo` and `make test`. Both create the virtual
# environment in .venv when it is missing and install the project into it.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.ffmpc-installed

# ROS 2 from PyPI needs a writable HOME/log dir; discovery stays on this machine.
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export ROS_LOG_DIR ?= $(CURDIR)/.ros_log
export HOME ?= $(CURDIR)

.PHONY: demo test lint bench install clean

install: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	$(BIN)/python -m ffmpc_ros.ament  # ros2 run layout (editable installs skip data-files)
	$(BIN)/ffmpc check
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/ffmpc demo

test: $(STAMP)
	$(BIN)/python -m pytest -q $(PYTEST_ARGS)

lint: $(STAMP)
	$(BIN)/ruff check ffmpc_core sim_bridge ffmpc_ros tests benchmarks
	$(BIN)/ruff format --check ffmpc_core sim_bridge ffmpc_ros tests benchmarks

bench: $(STAMP)
	$(BIN)/ffmpc bench mpc

clean:
	rm -rf $(VENV) .ros_log .pytest_cache
