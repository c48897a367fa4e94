// Low-pass-filter integrator of the torque-feedback formulation (see lowpass.hpp); the Python
// reference is ffmpc_core/lowpass.py.
#include "lowpass.hpp"

#include <cmath>
#include <sstream>

#include <crocoddyl/core/costs/cost-sum.hpp>
#include <crocoddyl/core/states/euclidean.hpp>
#include <crocoddyl/multibody/actions/contact-fwddyn.hpp>
#include <crocoddyl/multibody/actions/free-fwddyn.hpp>

namespace ffmpc {

namespace {

/// The cost data of crocoddyl's free or contact forward-dynamics data (null for other models).
std::shared_ptr<crocoddyl::CostDataSum> cost_data_of(
    const std::shared_ptr<crocoddyl::DifferentialActionDataAbstract>& data) {
  if (auto* free = dynamic_cast<crocoddyl::DifferentialActionDataFreeFwdDynamics*>(data.get())) {
    return free->costs;
  }
  if (auto* contact =
          dynamic_cast<crocoddyl::DifferentialActionDataContactFwdDynamics*>(data.get())) {
    return contact->costs;
  }
  return nullptr;
}

}  // namespace

IntegratedActionModelLPF::IntegratedActionModelLPF(
    std::shared_ptr<DifferentialActionModelAbstract> differential, double dt,
    double cutoff_frequency, double lowpass_input_weight, const std::string& torque_cost,
    const Eigen::MatrixXd& constraint_matrix, const Eigen::VectorXd& control_scale,
    bool control_rows)
    : Base(std::make_shared<crocoddyl::StateVector>(3 * differential->get_state()->get_nv()),
           differential->get_state()->get_nv(), 0,
           ConstraintRows(constraint_matrix, control_scale,
                          3 * differential->get_state()->get_nv(),
                          differential->get_state()->get_nv(), control_rows)
               .ng(),
           0, static_cast<std::size_t>(constraint_matrix.rows()), 0),
      differential_(differential),
      dt_(dt),
      cutoff_frequency_(cutoff_frequency),
      alpha_(0.0),
      lowpass_input_weight_(lowpass_input_weight),
      torque_cost_(torque_cost),
      nv_(differential->get_state()->get_nv()),
      constraint_rows_(constraint_matrix, control_scale, 3 * nv_, nv_, control_rows) {
  if (differential->get_state()->get_nq() != nv_) {
    throw ModelError("IntegratedActionModelLPF needs nq == nv (Euclidean configuration space)");
  }
  if (differential->get_nu() != nv_) {
    throw ModelError(
        "IntegratedActionModelLPF: the differential model must be fully actuated (nu == nv)");
  }
  if (!std::isfinite(dt) || dt <= 0.0) {
    throw ConfigError("IntegratedActionModelLPF: dt must be > 0 s");
  }
  if (std::isnan(cutoff_frequency) || cutoff_frequency < 0.0) {
    throw ConfigError("IntegratedActionModelLPF: cutoff_frequency must be in [0, inf] Hz");
  }
  if (!std::isfinite(lowpass_input_weight) || lowpass_input_weight < 0.0) {
    throw ConfigError("IntegratedActionModelLPF: lowpass_input_weight must be >= 0");
  }
  alpha_ = std::exp(-2.0 * M_PI * cutoff_frequency * dt);  // eq 13
}

void IntegratedActionModelLPF::require_torque_residual(const IntegratedActionDataLPF& d) const {
  if (!d.torque_residual) {
    throw ModelError("a running low-pass model needs the '" + torque_cost_ + "' cost (eq 25.3)");
  }
}

void IntegratedActionModelLPF::calc(const std::shared_ptr<ActionDataAbstract>& data,
                                    const Eigen::Ref<const VectorXd>& x,
                                    const Eigen::Ref<const VectorXd>& u) {
  check_size(x.size(), 3 * nv_, "IntegratedActionModelLPF: x");
  check_size(u.size(), nv_, "IntegratedActionModelLPF: u");
  auto* d = static_cast<IntegratedActionDataLPF*>(data.get());
  require_torque_residual(*d);
  const std::size_t nv = nv_;
  const auto tau = x.tail(nv);
  const auto& dd = d->differential;
  differential_->calc(dd, x.head(2 * nv), tau);
  // v⁺ = v + Δt·q̈; q⁺ = q + Δt·v⁺; τ⁺ = α·τ + (1 − α)·w (eq 13–14a)
  d->xnext.segment(nv, nv) = x.segment(nv, nv) + dt_ * dd->xout;
  d->xnext.head(nv) = x.head(nv) + dt_ * d->xnext.segment(nv, nv);
  d->xnext.tail(nv) = alpha_ * tau + (1.0 - alpha_) * u;
  // eq 28: r_w = w − τ_g(q, λ^r), τ_g = τ − r_torque
  d->lowpass_residual = u - (tau - d->torque_residual->r);
  d->cost = dt_ * (dd->cost + 0.5 * lowpass_input_weight_ * d->lowpass_residual.squaredNorm());
  constraint_rows_.calc(d->g, x, u);
}

void IntegratedActionModelLPF::calc(const std::shared_ptr<ActionDataAbstract>& data,
                                    const Eigen::Ref<const VectorXd>& x) {
  check_size(x.size(), 3 * nv_, "IntegratedActionModelLPF: x");
  auto* d = static_cast<IntegratedActionDataLPF*>(data.get());
  if (d->torque_residual) {
    // The terminal torque term: the differential cost at control τ (the state's torque).
    differential_->calc(d->differential, x.head(2 * nv_), x.tail(nv_));
  } else {
    differential_->calc(d->differential, x.head(2 * nv_));
  }
  d->xnext = x;
  d->cost = d->differential->cost;
  constraint_rows_.calc(d->g, x);
}

void IntegratedActionModelLPF::calcDiff(const std::shared_ptr<ActionDataAbstract>& data,
                                        const Eigen::Ref<const VectorXd>& x,
                                        const Eigen::Ref<const VectorXd>& u) {
  check_size(x.size(), 3 * nv_, "IntegratedActionModelLPF: x");
  check_size(u.size(), nv_, "IntegratedActionModelLPF: u");
  auto* d = static_cast<IntegratedActionDataLPF*>(data.get());
  require_torque_residual(*d);
  const std::size_t nv = nv_, n2 = 2 * nv;
  const auto tau = x.tail(nv);
  const auto& dd = d->differential;
  differential_->calcDiff(dd, x.head(n2), tau);

  // v⁺ = v + Δt·q̈(q, v, τ): rows nv..2nv; q⁺ = q + Δt·v⁺: rows 0..nv; τ⁺ = α·τ + (1 − α)·w.
  auto Fv = d->Fx.middleRows(nv, nv);
  Fv.leftCols(n2) = dt_ * dd->Fx;
  Fv.rightCols(nv) = dt_ * dd->Fu;
  Fv.middleCols(nv, nv).diagonal().array() += 1.0;
  d->Fx.topRows(nv) = dt_ * Fv;
  d->Fx.topLeftCorner(nv, nv).diagonal().array() += 1.0;
  d->Fx.bottomRows(nv).setZero();
  d->Fx.bottomRightCorner(nv, nv).diagonal().setConstant(alpha_);
  d->Fu.setZero();
  d->Fu.bottomRows(nv).diagonal().setConstant(1.0 - alpha_);

  // ℓ0 with u = τ (its control derivatives are τ-state derivatives), then eq 28:
  // r_w = w − τ_g(q, λ^r(q, v, τ)), ∂τ_g/∂(q, v) = −R_x, ∂τ_g/∂τ = I − R_u.
  const double cw = lowpass_input_weight_;
  const auto& residual = *d->torque_residual;
  d->lowpass_residual = u - tau + residual.r;
  auto& G = d->dtau_g_dx;
  G.leftCols(n2) = -residual.Rx;
  G.rightCols(nv) = -residual.Ru;
  G.rightCols(nv).diagonal().array() += 1.0;

  auto& Lxx = d->Lxx;
  Lxx.topLeftCorner(n2, n2) = dd->Lxx;
  Lxx.topRightCorner(n2, nv) = dd->Lxu;
  Lxx.bottomLeftCorner(nv, n2) = dd->Lxu.transpose();
  Lxx.bottomRightCorner(nv, nv) = dd->Luu;
  d->cw_gtg.noalias() = G.transpose() * G;
  Lxx.noalias() += cw * d->cw_gtg;
  Lxx *= dt_;
  d->Lx.head(n2) = dd->Lx;
  d->Lx.tail(nv) = dd->Lu;
  d->Lx.noalias() -= cw * (G.transpose() * d->lowpass_residual);
  d->Lx *= dt_;
  d->Lxu.noalias() = (-cw * dt_) * G.transpose();
  d->Lu = (cw * dt_) * d->lowpass_residual;
  d->Luu.setZero();
  d->Luu.diagonal().setConstant(cw * dt_);
  constraint_rows_.calcDiff(d->Gx, d->Gu);
}

void IntegratedActionModelLPF::calcDiff(const std::shared_ptr<ActionDataAbstract>& data,
                                        const Eigen::Ref<const VectorXd>& x) {
  // Terminal: x⁺ = x, cost ℓ0(q, v) [+ c3·½‖τ − g(q)‖² when the torque cost is there].
  check_size(x.size(), 3 * nv_, "IntegratedActionModelLPF: x");
  auto* d = static_cast<IntegratedActionDataLPF*>(data.get());
  const std::size_t nv = nv_, n2 = 2 * nv_;
  const auto& dd = d->differential;
  d->Fx.setIdentity();
  d->Fu.setZero();
  d->Lx.setZero();
  d->Lxx.setZero();
  if (d->torque_residual) {
    // derivatives w.r.t. the control τ are derivatives w.r.t. the τ state
    differential_->calcDiff(dd, x.head(n2), x.tail(nv));
    d->Lx.tail(nv) = dd->Lu;
    d->Lxx.topRightCorner(n2, nv) = dd->Lxu;
    d->Lxx.bottomLeftCorner(nv, n2) = dd->Lxu.transpose();
    d->Lxx.bottomRightCorner(nv, nv) = dd->Luu;
  } else {
    differential_->calcDiff(dd, x.head(n2));
  }
  d->Lx.head(n2) = dd->Lx;
  d->Lxx.topLeftCorner(n2, n2) = dd->Lxx;
  constraint_rows_.calcDiff(d->Gx, d->Gu);
}

std::shared_ptr<crocoddyl::ActionDataAbstract> IntegratedActionModelLPF::createData() {
  return std::allocate_shared<IntegratedActionDataLPF>(
      Eigen::aligned_allocator<IntegratedActionDataLPF>(), this);
}

bool IntegratedActionModelLPF::checkData(const std::shared_ptr<ActionDataAbstract>& data) {
  auto d = std::dynamic_pointer_cast<IntegratedActionDataLPF>(data);
  return d != nullptr && differential_->checkData(d->differential);
}

std::shared_ptr<crocoddyl::ActionModelBase> IntegratedActionModelLPF::cloneAsDouble() const {
  return std::make_shared<IntegratedActionModelLPF>(*this);
}

std::shared_ptr<crocoddyl::ActionModelBase> IntegratedActionModelLPF::cloneAsFloat() const {
  throw std::logic_error("IntegratedActionModelLPF exists in double precision only");
}

void IntegratedActionModelLPF::print(std::ostream& os) const {
  os << "IntegratedActionModelLPF {dt=" << dt_ << ", cutoff_frequency=" << cutoff_frequency_
     << ", alpha=" << alpha_ << ", lowpass_input_weight=" << lowpass_input_weight_
     << ", ng=" << ng_ << "}";
}

IntegratedActionDataLPF::IntegratedActionDataLPF(IntegratedActionModelLPF* const model)
    : Base(model),
      differential(model->get_differential()->createData()),
      lowpass_residual(VectorXd::Zero(model->get_nv())),
      dtau_g_dx(MatrixXd::Zero(model->get_nv(), 3 * model->get_nv())),
      cw_gtg(MatrixXd::Zero(3 * model->get_nv(), 3 * model->get_nv())) {
  const std::shared_ptr<crocoddyl::CostDataSum> costs = cost_data_of(differential);
  if (costs) {
    const auto it = costs->costs.find(model->get_torque_cost());
    if (it != costs->costs.end()) {
      torque_residual = it->second->residual;
    }
  }
}

}  // namespace ffmpc
