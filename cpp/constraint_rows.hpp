// The hard-constraint rows of the native action models (issue 23; see ffmpc_core/constraints.py,
// whose OcpBounds builds them): g = [S x; c .* u], linear in (x, u). S (n_s x nx) stacks the
// state-only rows (the state box and the 3-D force-feedback friction-cone pyramid, each row
// divided by its limit); the control rows c .* u (c: 1 / the control limits, nu) exist in
// running nodes only. Every row is thus a fraction of its limit: ADMM sees rows of one scale. The bounds g_lb, g_ub live in crocoddyl's
// ActionModelAbstract (set from Python); mim_solvers' SolverCSQP reads g, Gx, Gu and the bounds.
#pragma once

#include <cstddef>

#include <Eigen/Core>

#include "errors.hpp"

namespace ffmpc {

struct ConstraintRows {
  /// S: the state-only rows (n_s x nx; 0 rows: no constraint); `control_scale` c (nu): the
  /// control rows are c .* u; `control`: whether there are control rows (a running node).
  ConstraintRows(const Eigen::MatrixXd& state_matrix, const Eigen::VectorXd& control_scale,
                 std::size_t nx, std::size_t nu, bool control)
      : state_matrix(state_matrix),
        control_scale(control_scale),
        nx(nx),
        nu(nu),
        control(control && state_matrix.rows() > 0) {
    if (state_matrix.rows() > 0 && static_cast<std::size_t>(state_matrix.cols()) != nx) {
      throw ConfigError("constraint matrix has " + std::to_string(state_matrix.cols()) +
                        " columns, expected the state size " + std::to_string(nx));
    }
    if (!state_matrix.allFinite()) {
      throw ConfigError("constraint matrix must be finite");
    }
    if (this->control && (static_cast<std::size_t>(control_scale.size()) != nu ||
                          !control_scale.allFinite())) {
      throw ConfigError("constraint control scale must have " + std::to_string(nu) +
                        " finite entries");
    }
  }

  std::size_t n_state() const { return static_cast<std::size_t>(state_matrix.rows()); }
  /// Rows of a call with a control (running) and of a call without (terminal).
  std::size_t ng() const { return n_state() + (control ? nu : 0); }
  std::size_t ng_T() const { return n_state(); }

  /// g = [S x; u] (the control rows only when there are, and u is given).
  template <typename G, typename X, typename U>
  void calc(G& g, const X& x, const U& u) const {
    const std::size_t ns = n_state();
    if (ns == 0) return;
    g.head(ns).noalias() = state_matrix * x;
    if (control) g.segment(ns, nu) = control_scale.cwiseProduct(u);
  }
  template <typename G, typename X>
  void calc(G& g, const X& x) const {
    const std::size_t ns = n_state();
    if (ns == 0) return;
    g.head(ns).noalias() = state_matrix * x;
  }
  /// Gx = [S; 0], Gu = [0; diag(c)] (constant).
  template <typename M1, typename M2>
  void calcDiff(M1& Gx, M2& Gu) const {
    const std::size_t ns = n_state();
    if (ns == 0) return;
    Gx.topRows(ns) = state_matrix;
    if (control) {
      Gx.middleRows(ns, nu).setZero();
      Gu.topRows(ns).setZero();
      Gu.middleRows(ns, nu).setZero();
      Gu.middleRows(ns, nu).diagonal() = control_scale;
    }
  }

  Eigen::MatrixXd state_matrix;
  Eigen::VectorXd control_scale;
  std::size_t nx, nu;
  bool control;
};

}  // namespace ffmpc
