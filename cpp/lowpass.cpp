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
    bool control_rows, const std::string& torque_integration)
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
      next_torque_(torque_integration == "next"),
      state_gain_(1.0),
      control_gain_(0.0),
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
  if (torque_integration != "current" && torque_integration != "next") {
    throw ConfigError("IntegratedActionModelLPF: torque_integration must be 'current' or 'next'");
  }
  alpha_ = std::exp(-2.0 * M_PI * cutoff_frequency * dt);  // eq 13
  if (next_torque_) {
    state_gain_ = alpha_;
    control_gain_ = 1.0 - alpha_;
  }
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
  // τ_a = s_x·τ + s_u·w: τ ("current", eq 14a) or τ⁺ = α·τ + (1 − α)·w ("next")
  d->applied_torque = state_gain_ * x.tail(nv) + control_gain_ * u;
  const auto& dd = d->differential;
  differential_->calc(dd, x.head(2 * nv), d->applied_torque);
  // v⁺ = v + Δt·q̈; q⁺ = q + Δt·v⁺; τ⁺ = α·τ + (1 − α)·w (eq 13–14a)
  d->xnext.segment(nv, nv) = x.segment(nv, nv) + dt_ * dd->xout;
  d->xnext.head(nv) = x.head(nv) + dt_ * d->xnext.segment(nv, nv);
  d->xnext.tail(nv) = alpha_ * x.tail(nv) + (1.0 - alpha_) * u;
  // eq 28: r_w = w − τ_g(q, λ^r), τ_g = τ_a − r_torque
  d->lowpass_residual = u - (d->applied_torque - d->torque_residual->r);
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
  const double sx = state_gain_, su = control_gain_;
  d->applied_torque = sx * x.tail(nv) + su * u;
  const auto& dd = d->differential;
  differential_->calcDiff(dd, x.head(n2), d->applied_torque);

  // v⁺ = v + Δt·q̈(q, v, τ_a): rows nv..2nv; q⁺ = q + Δt·v⁺: rows 0..nv; τ⁺ = α·τ + (1 − α)·w;
  // τ_a = s_x·τ + s_u·w.
  auto Fv = d->Fx.middleRows(nv, nv);
  Fv.leftCols(n2) = dt_ * dd->Fx;
  Fv.rightCols(nv) = (dt_ * sx) * dd->Fu;
  Fv.middleCols(nv, nv).diagonal().array() += 1.0;
  d->Fx.topRows(nv) = dt_ * Fv;
  d->Fx.topLeftCorner(nv, nv).diagonal().array() += 1.0;
  d->Fx.bottomRows(nv).setZero();
  d->Fx.bottomRightCorner(nv, nv).diagonal().setConstant(alpha_);
  d->Fu.setZero();
  if (next_torque_) {
    d->Fu.middleRows(nv, nv) = (dt_ * su) * dd->Fu;
    d->Fu.topRows(nv) = dt_ * d->Fu.middleRows(nv, nv);
  }
  d->Fu.bottomRows(nv).diagonal().setConstant(1.0 - alpha_);

  // In y = (q, v, τ_a): ℓ0 with u = τ_a, then eq 28 r_w = w − τ_g(y), ∂τ_g/∂(q, v) = −R_x,
  // ∂τ_g/∂τ_a = I − R_u: M = H0 + c_w·GᵀG, h = g0 − c_w·Gᵀr_w. Mapped to (x, w) through
  // J = ∂y/∂x = diag(I, s_x·I), ∂y/∂w = s_u·E_τ: Lxx = Δt·JᵀMJ, Lx = Δt·Jᵀh,
  // Lxu = Δt·Jᵀ(s_u·M_{:,τ} − c_w·Gᵀ), Lu = Δt·(s_u·h_τ + c_w·r_w),
  // Luu = Δt·(s_u²·M_ττ − c_w·s_u·(G_τ + G_τᵀ) + c_w·I).
  const double cw = lowpass_input_weight_;
  const auto& residual = *d->torque_residual;
  d->lowpass_residual = u - d->applied_torque + residual.r;
  auto& G = d->dtau_g_dx;
  G.leftCols(n2) = -residual.Rx;
  G.rightCols(nv) = -residual.Ru;
  G.rightCols(nv).diagonal().array() += 1.0;

  auto& M = d->hessian;
  M.topLeftCorner(n2, n2) = dd->Lxx;
  M.topRightCorner(n2, nv) = dd->Lxu;
  M.bottomLeftCorner(nv, n2) = dd->Lxu.transpose();
  M.bottomRightCorner(nv, nv) = dd->Luu;
  d->cw_gtg.noalias() = G.transpose() * G;
  M.noalias() += cw * d->cw_gtg;
  auto& h = d->gradient;
  h.head(n2) = dd->Lx;
  h.tail(nv) = dd->Lu;
  h.noalias() -= cw * (G.transpose() * d->lowpass_residual);

  d->Lxx = dt_ * M;
  d->Lx = dt_ * h;
  d->Lxu.noalias() = (-cw * dt_) * G.transpose();
  d->Lu = (cw * dt_) * d->lowpass_residual;
  d->Luu.setZero();
  d->Luu.diagonal().setConstant(cw * dt_);
  if (next_torque_) {
    d->Lxu.noalias() += (dt_ * su) * M.rightCols(nv);
    d->Lu.noalias() += (dt_ * su) * h.tail(nv);
    d->Luu.noalias() += (dt_ * su * su) * M.bottomRightCorner(nv, nv);
    d->Luu.noalias() -= (dt_ * cw * su) * G.rightCols(nv);
    d->Luu.noalias() -= (dt_ * cw * su) * G.rightCols(nv).transpose();
    // rows and columns of τ scaled by s_x = α (J = diag(I, α·I))
    d->Lxx.bottomRows(nv) *= sx;
    d->Lxx.rightCols(nv) *= sx;
    d->Lx.tail(nv) *= sx;
    d->Lxu.bottomRows(nv) *= sx;
  }
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
     << ", torque_integration=" << get_torque_integration() << ", ng=" << ng_ << "}";
}

IntegratedActionDataLPF::IntegratedActionDataLPF(IntegratedActionModelLPF* const model)
    : Base(model),
      differential(model->get_differential()->createData()),
      lowpass_residual(VectorXd::Zero(model->get_nv())),
      applied_torque(VectorXd::Zero(model->get_nv())),
      dtau_g_dx(MatrixXd::Zero(model->get_nv(), 3 * model->get_nv())),
      cw_gtg(MatrixXd::Zero(3 * model->get_nv(), 3 * model->get_nv())),
      hessian(MatrixXd::Zero(3 * model->get_nv(), 3 * model->get_nv())),
      gradient(VectorXd::Zero(3 * model->get_nv())) {
  const std::shared_ptr<crocoddyl::CostDataSum> costs = cost_data_of(differential);
  if (costs) {
    const auto it = costs->costs.find(model->get_torque_cost());
    if (it != costs->costs.end()) {
      torque_residual = it->second->residual;
    }
  }
}

}  // namespace ffmpc
