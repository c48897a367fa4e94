// Torque-feedback formulation (paper Sec. IV, eq 9, 13, 14; cost eq 28): the low-pass-filter
// integrator on x = (q, v, τ), u = w, wrapping a crocoddyl differential model whose control is τ.
// C++ port of ffmpc_core/lowpass.py's IntegratedActionModelLPF (the readable reference): same
// step, cost and derivatives.
#ifndef FFMPC_CPP_LOWPASS_HPP_
#define FFMPC_CPP_LOWPASS_HPP_

#include <memory>
#include <stdexcept>
#include <string>

#include <crocoddyl/core/action-base.hpp>
#include <crocoddyl/core/diff-action-base.hpp>
#include <crocoddyl/core/residual-base.hpp>

#include "constraint_rows.hpp"
#include "errors.hpp"
#include "residuals.hpp"

namespace ffmpc {

/// Eq 13–14 and 28 as a crocoddyl action model on x = (q, v, τ) (rad, rad/s, N·m), u = w (N·m).
///
/// Dynamics: q̈ from the differential model at (q, v) with control τ_a; v⁺ = v + Δt·q̈,
/// q⁺ = q + Δt·v⁺ (nq == nv: Euclidean configuration space), τ⁺ = α·τ + (1 − α)·w,
/// α = exp(−2π·f_c·Δt). τ_a, the torque the joints accelerate under in the interval
/// (`torque_integration`): "current" τ (eq 14a) or "next" τ⁺ (the authors'
/// tau_plus_integration). Running cost Δt·[ℓ0(q, v, τ_a) + c_w·½·‖w − τ_g‖²] with
/// τ_g = τ_a − r_torque (r_torque: the residual of the differential model's cost named
/// `torque_cost`, eq 25.3). calc(x)/calcDiff(x) (terminal): ℓ0(q, v), x⁺ = x; when the
/// (terminal) differential model has the `torque_cost` cost, its cost is evaluated at control τ
/// (the state's filtered torque): the terminal torque regularisation c3·½‖τ − g(q)‖².
/// Hessians: the differential model's (Gauss–Newton) ones mapped to (q, v, τ), plus the exact
/// Gauss–Newton term of eq 28.
struct IntegratedActionDataLPF;

class IntegratedActionModelLPF : public crocoddyl::ActionModelAbstract {
 public:
  EIGEN_MAKE_ALIGNED_OPERATOR_NEW
  typedef crocoddyl::ActionModelAbstract Base;
  typedef crocoddyl::ActionDataAbstract ActionDataAbstract;
  typedef crocoddyl::DifferentialActionModelAbstract DifferentialActionModelAbstract;
  typedef crocoddyl::MathBaseTpl<double>::VectorXs VectorXd;
  typedef crocoddyl::MathBaseTpl<double>::MatrixXs MatrixXd;

  /// `differential`: control τ (nu == nv), nq == nv. `dt` Δt in s (> 0); `cutoff_frequency`
  /// f_c in Hz, in [0, ∞]; `lowpass_input_weight` c_w in 1/(N·m)², ≥ 0.
  /// `constraint_matrix`: the state-only constraint rows S on (q, v, τ) (0 rows: none);
  /// `control_rows`: also the rows control_scale .* w (a running node). Bounds: g_lb, g_ub.
  /// `torque_integration`: "current" or "next" (see the class comment).
  IntegratedActionModelLPF(std::shared_ptr<DifferentialActionModelAbstract> differential,
                           double dt, double cutoff_frequency, double lowpass_input_weight,
                           const std::string& torque_cost,
                           const Eigen::MatrixXd& constraint_matrix,
                           const Eigen::VectorXd& control_scale, bool control_rows,
                           const std::string& torque_integration = "current");
  virtual ~IntegratedActionModelLPF() = default;

  void calc(const std::shared_ptr<ActionDataAbstract>& data,
            const Eigen::Ref<const VectorXd>& x, const Eigen::Ref<const VectorXd>& u) override;
  void calc(const std::shared_ptr<ActionDataAbstract>& data,
            const Eigen::Ref<const VectorXd>& x) override;
  void calcDiff(const std::shared_ptr<ActionDataAbstract>& data,
                const Eigen::Ref<const VectorXd>& x,
                const Eigen::Ref<const VectorXd>& u) override;
  void calcDiff(const std::shared_ptr<ActionDataAbstract>& data,
                const Eigen::Ref<const VectorXd>& x) override;
  std::shared_ptr<ActionDataAbstract> createData() override;
  bool checkData(const std::shared_ptr<ActionDataAbstract>& data) override;
  std::shared_ptr<crocoddyl::ActionModelBase> cloneAsDouble() const override;
  std::shared_ptr<crocoddyl::ActionModelBase> cloneAsFloat() const override;
  void print(std::ostream& os) const override;

  const std::shared_ptr<DifferentialActionModelAbstract>& get_differential() const {
    return differential_;
  }
  double get_dt() const { return dt_; }
  double get_cutoff_frequency() const { return cutoff_frequency_; }
  double get_alpha() const { return alpha_; }
  double get_lowpass_input_weight() const { return lowpass_input_weight_; }
  std::size_t get_nv() const { return nv_; }
  const std::string& get_torque_cost() const { return torque_cost_; }
  /// "current" (τ_a = τ) or "next" (τ_a = τ⁺).
  std::string get_torque_integration() const { return next_torque_ ? "next" : "current"; }
  const ConstraintRows& get_constraint_rows() const { return constraint_rows_; }

 private:
  /// ModelError unless the differential model's data has the torque cost (eq 25.3).
  void require_torque_residual(const IntegratedActionDataLPF& d) const;

  std::shared_ptr<DifferentialActionModelAbstract> differential_;
  double dt_;
  double cutoff_frequency_;
  double alpha_;
  double lowpass_input_weight_;
  std::string torque_cost_;
  bool next_torque_;  ///< τ_a = τ⁺ ("next") instead of τ ("current")
  double state_gain_;    ///< s_x = ∂τ_a/∂τ: 1 ("current") or α ("next")
  double control_gain_;  ///< s_u = ∂τ_a/∂w: 0 ("current") or 1 − α ("next")
  std::size_t nv_;
  ConstraintRows constraint_rows_;
};

/// Workspace of IntegratedActionModelLPF.
struct IntegratedActionDataLPF : public crocoddyl::ActionDataAbstract {
  EIGEN_MAKE_ALIGNED_OPERATOR_NEW
  typedef crocoddyl::ActionDataAbstract Base;
  typedef crocoddyl::MathBaseTpl<double>::VectorXs VectorXd;
  typedef crocoddyl::MathBaseTpl<double>::MatrixXs MatrixXd;

  explicit IntegratedActionDataLPF(IntegratedActionModelLPF* const model);
  virtual ~IntegratedActionDataLPF() = default;

  /// The differential model's data (q̈, λ^r, ℓ0 after calc).
  std::shared_ptr<crocoddyl::DifferentialActionDataAbstract> differential;
  /// Its eq 25.3 residual data (null when the differential model has no such cost).
  std::shared_ptr<crocoddyl::ResidualDataAbstract> torque_residual;
  VectorXd lowpass_residual;  ///< w − τ_g of eq 28 after calc, N·m
  VectorXd applied_torque;    ///< τ_a after calc, N·m
  MatrixXd dtau_g_dx;         ///< ∂τ_g/∂(q, v, τ_a) (nv × 3nv) after calcDiff
  MatrixXd cw_gtg;            ///< c_w·Gᵀ·G workspace (3nv × 3nv)
  MatrixXd hessian;           ///< M = H0 + c_w·GᵀG in (q, v, τ_a) (3nv × 3nv)
  VectorXd gradient;          ///< h = g0 − c_w·Gᵀ·r_w in (q, v, τ_a) (3nv)
};

}  // namespace ffmpc

#endif  // FFMPC_CPP_LOWPASS_HPP_
