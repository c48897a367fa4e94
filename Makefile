# The two commands of the README: `make demo` and `make test`. Both create the virtual
# environment in .venv when it is missing and install the project into it.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.ffmpc-installed
NATIVE := $(VENV)/.ffmpc-native
DOCS_STAMP := $(VENV)/.ffmpc-docs

# ROS 2 from PyPI needs a writable HOME/log dir; discovery stays on this machine.
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export ROS_LOG_DIR ?= $(CURDIR)/.ros_log
export HOME ?= $(CURDIR)

.PHONY: demo test lint bench install native docs clean

define BUILD_REQUIRES
try:
    import tomllib
except ImportError:  # Python 3.10
    from pip._vendor import tomli as tomllib
with open("pyproject.toml", "rb") as f:
    print("\n".join(tomllib.load(f)["build-system"]["requires"]))
endef
export BUILD_REQUIRES

define DOCS_REQUIRES
import tomllib
with open("pyproject.toml", "rb") as f:
    print("\n".join(tomllib.load(f)["project"]["optional-dependencies"]["docs"]))
endef
export DOCS_REQUIRES

install: $(STAMP) $(NATIVE)

# The build requirements (pyproject [build-system] requires: scikit-build-core, the pinned
# pin/crocoddyl/eigen, CMake) go into the venv first, so that the editable install and every
# rebuild of the C++ module (`make native`) run without build isolation: same ABI, ~10x faster.
$(STAMP): pyproject.toml CMakeLists.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	# setuptools >= 70.1 builds wheels itself: without it (or `wheel`), pip >= 25.3 cannot build
	# the sdists of the ROS wheels' dependencies (empy) without build isolation.
	$(BIN)/python -m pip install --quiet --upgrade pip 'setuptools>=70.1' wheel
	$(BIN)/python -c "$$BUILD_REQUIRES" > $(VENV)/build-requirements.txt
	$(BIN)/python -m pip install --quiet -r $(VENV)/build-requirements.txt
	$(BIN)/python -m pip install --quiet --no-build-isolation -e '.[dev]'
	$(BIN)/python -m ffmpc_ros.ament  # ros2 run layout, launchers run by this venv's python
	$(BIN)/ffmpc check
	touch $(STAMP) $(NATIVE)

# Rebuild the C++ module ffmpc_core._native after editing cpp/, and the message package
# ffmpc_msgs after editing msg/ (incremental, in build/); the targets below do it on their own
# when a cpp/ or msg/ file is newer than the last build, and when a scenario, launch or layout file
# changed (the build installs them into share/ffmpc_ros).
native: $(NATIVE)

$(NATIVE): $(STAMP) $(wildcard cpp/*.cpp cpp/*.hpp msg/*.msg msg/*.cmake msg/CMakeLists.txt msg/tf2_msgs/*/* msg/tf2_msgs/CMakeLists.txt msg/linear_feedback_controller_msgs/*/* msg/linear_feedback_controller_msgs/CMakeLists.txt ffmpc_core/scenarios/*.yaml ffmpc_ros/ros_layout/*/* share/ffmpc_ros/*/*)
	$(BIN)/python -m pip install --quiet --no-build-isolation --no-deps -e .
	$(BIN)/python -m ffmpc_ros.ament >/dev/null  # pip rewrote the launchers (env python3)
	touch $(NATIVE)

demo: $(STAMP) $(NATIVE)
	$(BIN)/ffmpc demo

test: $(STAMP) $(NATIVE) $(DOCS_STAMP)
	$(BIN)/python -m pytest -q $(PYTEST_ARGS)

# The manual (docs/, Sphinx + MyST): warnings are errors (broken links, missing references, an
# undocumented public object of ffmpc_core, an unmapped paper equation). The reference pages are
# generated from the code on every build (docs/_ext/ffmpc_docs); incremental in docs/_build.
# The docs extra of pyproject.toml goes into the venv (tests/test_docs_site.py builds it too).
$(DOCS_STAMP): $(STAMP) pyproject.toml
	$(BIN)/python -c "$$DOCS_REQUIRES" > $(VENV)/docs-requirements.txt
	$(BIN)/python -m pip install --quiet -r $(VENV)/docs-requirements.txt
	touch $(DOCS_STAMP)

docs: $(STAMP) $(NATIVE) $(DOCS_STAMP)
	$(BIN)/sphinx-build -W --keep-going -q -b html docs docs/_build/html
	@echo "manual: docs/_build/html/index.html"

lint: $(STAMP)
	$(BIN)/ruff check ffmpc_core sim_bridge studies ffmpc_ros tests benchmarks docs
	$(BIN)/python tests/layer_check.py  # ffmpc_core <- sim_bridge <- ffmpc_ros <- studies, no cycles
	$(BIN)/ruff format --check ffmpc_core sim_bridge studies ffmpc_ros tests benchmarks docs
	$(BIN)/mypy  # ffmpc_core, sim_bridge, studies, ffmpc_ros: pyproject.toml [tool.mypy]

bench: $(STAMP) $(NATIVE)
	$(BIN)/ffmpc bench mpc

clean:
	rm -rf $(VENV) .ros_log .pytest_cache .mypy_cache build docs/_build docs/reference/_autosummary
