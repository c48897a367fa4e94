// Translation of ffmpc's C++ exceptions into ffmpc_core.errors (one exception hierarchy).
#include "errors.hpp"

#include <boost/python.hpp>

namespace bp = boost::python;

namespace ffmpc {
namespace {

template <class Error>
void translate(const Error& error, const char* name) {
  // ffmpc_core.errors is pure Python (no dependency): importing it here cannot recurse.
  bp::object cls = bp::import("ffmpc_core.errors").attr(name);
  PyErr_SetString(cls.ptr(), error.what());
}

void translate_config(const ConfigError& error) { translate(error, "ConfigError"); }
void translate_input(const InputError& error) { translate(error, "InputError"); }

}  // namespace

void expose_errors() {
  bp::register_exception_translator<ConfigError>(&translate_config);
  bp::register_exception_translator<InputError>(&translate_input);
}

}  // namespace ffmpc
