// C++ counterparts of ffmpc_core.errors: thrown by native setters, translated to the Python
// exception classes of ffmpc_core.errors (ConfigError, InputError) by expose_errors().
#pragma once

#include <cstddef>
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

/// A model is used in a way it does not support (missing contact or cost data, a running
/// low-pass step without the torque cost of eq 25.3): ffmpc_core.errors.ModelError in Python
/// (translator registered by expose_residuals()).
struct ModelError : public std::runtime_error {
  using std::runtime_error::runtime_error;
};

/// InputError unless `size` == `expected` ("<what> has <size> entries, expected <expected>").
inline void check_size(std::ptrdiff_t size, std::size_t expected, const char* what) {
  if (static_cast<std::size_t>(size) != expected) {
    throw InputError(std::string(what) + " has " + std::to_string(size) +
                     " entries, expected " + std::to_string(expected));
  }
}

/// Register the exception translators (call once, first, in the module init).
void expose_errors();

}  // namespace ffmpc
