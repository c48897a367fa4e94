// ffmpc_core._native: the native crocoddyl action models of ffmpc (boost::python).
//
// Convention: each model file cpp/<name>.cpp defines `void ffmpc::expose_<name>()` that registers
// its classes; add one declaration and one call line below per file. Python must
// `import crocoddyl` before importing this module (ffmpc_core/native.py does).
#include <boost/python.hpp>
#include <eigenpy/eigenpy.hpp>

namespace bp = boost::python;

namespace ffmpc {
void expose_errors();  // cpp/errors.cpp: C++ ConfigError/InputError -> ffmpc_core.errors
void expose_soft_contact();
void expose_residuals();  // cpp/residuals_python.cpp
void expose_lowpass();    // cpp/lowpass_python.cpp
}  // namespace ffmpc

BOOST_PYTHON_MODULE(_native) {
  // crocoddyl's Python module registers ActionModelAbstract, StateVector, ... converters.
  bp::import("crocoddyl");
  eigenpy::enableEigenPy();
  bp::scope().attr("__doc__") = "Native (C++) crocoddyl action models of ffmpc.";
  ffmpc::expose_errors();
  ffmpc::expose_soft_contact();
  ffmpc::expose_residuals();
  ffmpc::expose_lowpass();
}
