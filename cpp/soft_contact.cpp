// Force-feedback action model (paper section V, eq 16-24; costs eq 25, 29): C++ port of
// ffmpc_core/soft_contact.py. Placeholder until the port lands: exposes the build check.
#include <boost/python.hpp>

namespace bp = boost::python;

namespace ffmpc {

/// Sum of 1..n, the build's smoke test from Python (`_native.build_check(3) == 6`).
static long build_check(long n) { return n * (n + 1) / 2; }

void expose_soft_contact() { bp::def("build_check", &build_check, bp::arg("n"), "Smoke test: n(n+1)/2."); }

}  // namespace ffmpc
