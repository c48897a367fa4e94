# Included by msg/CMakeLists.txt (ffmpc_msgs) and msg/tf2_msgs/CMakeLists.txt: where the
# ros-jazzy-* wheels are, for find_package and the rosidl generators.
# The ros-jazzy-* wheels install their CMake packages into the environment prefix
# (site-packages/../../..: the venv, or pip's build-isolation overlay): the prefix of the
# ament_package wheel the build requirements installed.
execute_process(
  COMMAND "${Python3_EXECUTABLE}" -c
          "import ament_package, pathlib; print(pathlib.Path(ament_package.__file__).parents[4])"
  OUTPUT_VARIABLE FFMPC_ROS_PREFIX
  OUTPUT_STRIP_TRAILING_WHITESPACE
  COMMAND_ERROR_IS_FATAL ANY)
list(PREPEND CMAKE_PREFIX_PATH "${FFMPC_ROS_PREFIX}")
set(ENV{AMENT_PREFIX_PATH} "${FFMPC_ROS_PREFIX}")
# The generators run with this interpreter (rosidl's code generators are Python packages).
set(PYTHON_EXECUTABLE "${Python3_EXECUTABLE}")
message(STATUS "${PROJECT_NAME}: ROS prefix ${FFMPC_ROS_PREFIX}")
