# Fix-ups every interface package generated here from the ros-jazzy-* wheels needs after
# rosidl_generate_interfaces (ffmpc_msgs in msg/, tf2_msgs in msg/tf2_msgs/; the recipe:
# ../../shared/DESIGN.md, "Custom .msg works from the wheels"). A macro: it runs in the calling
# directory's scope (its imported targets, its PROJECT_NAME).
macro(ffmpc_rosidl_include_fixups)
  # The wheels' exported rosidl_generator_py targets carry the include directories of the machine
  # that built them (/opt/python/...): point them at this interpreter's Python and NumPy headers.
  get_property(_ffmpc_imported DIRECTORY PROPERTY IMPORTED_TARGETS)
  foreach(_target IN LISTS _ffmpc_imported)
    get_target_property(_includes ${_target} INTERFACE_INCLUDE_DIRECTORIES)
    if(_includes MATCHES "^/opt/python/")
      set_target_properties(${_target} PROPERTIES
        INTERFACE_INCLUDE_DIRECTORIES "${Python3_INCLUDE_DIRS};${Python3_NumPy_INCLUDE_DIRS}")
    endif()
  endforeach()

  # rosidl_generator_py makes the Python and NumPy headers PUBLIC include directories of the
  # generated library, an exported target: with the venv inside the source tree (.venv) CMake
  # refuses to export them. Only this build needs them: keep them for the build interface.
  set(_ffmpc_py_target ${PROJECT_NAME}__rosidl_generator_py)
  get_target_property(_includes ${_ffmpc_py_target} INTERFACE_INCLUDE_DIRECTORIES)
  set(_build_includes "")
  foreach(_dir IN LISTS _includes)
    if(_dir MATCHES "^\\$<")
      list(APPEND _build_includes "${_dir}")
    else()
      list(APPEND _build_includes "$<BUILD_INTERFACE:${_dir}>")
    endif()
  endforeach()
  set_target_properties(${_ffmpc_py_target} PROPERTIES
    INTERFACE_INCLUDE_DIRECTORIES "${_build_includes}")
endmacro()
