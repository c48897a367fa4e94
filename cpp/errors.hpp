// C++ counterparts of ffmpc_core.errors: thrown by native setters, translated to the Python
// exception classes of ffmpc_core.errors (ConfigError, InputError) by expose_errors().
#pragma once

#include <stdexcept>
#include <string>

namespace ffmpc {

/// A configuration value is missing, out of range or inconsistent (ffmpc_core.errors.ConfigError).
struct ConfigError : public std::invalid_argument {
  using std::invalid_argument::invalid_argument;
};

/// A run-time input is malformed: NaN/Inf, wrong size (ffmpc_core.errors.InputError).
struct InputError : public std::invalid_argument {
  using std::invalid_argument::invalid_argument;
};

/// Register the exception translators (call once, first, in the module init).
void expose_errors();

}  // namespace ffmpc
