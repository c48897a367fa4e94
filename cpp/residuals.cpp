// Custom residuals of eq 25.3 and 25.5 (see residuals.hpp); the Python reference is
// ffmpc_core/rigid_contact.py.
#include "residuals.hpp"

#include "errors.hpp"

#include <stdexcept>

#include <pinocchio/algorithm/frames-derivatives.hpp>
#include <pinocchio/algorithm/frames.hpp>
#include <pinocchio/algorithm/kinematics-derivatives.hpp>
#include <pinocchio/algorithm/rnea-derivatives.hpp>
#include <pinocchio/algorithm/rnea.hpp>
#include <pinocchio/spatial/skew.hpp>

namespace ffmpc {

// ---- ResidualModelContactGravityTorque --------------------------------------------------------

ResidualModelContactGravityTorque::ResidualModelContactGravityTorque(
    std::shared_ptr<StateMultibody> state, std::size_t nu, bool world_aligned,
    const std::string& contact_name)
    : Base(state, state->get_nv(), nu, true, true, true),
      pin_model_(state->get_pinocchio()),
      world_aligned_(world_aligned),
      contact_name_(contact_name) {
  if (nu != state->get_nv()) {
    throw ConfigError("ResidualModelContactGravityTorque: nu must equal nv (full actuation)");
  }
}

void ResidualModelContactGravityTorque::calc(const std::shared_ptr<ResidualDataAbstract>& data,
                                             const Eigen::Ref<const VectorXd>& x,
                                             const Eigen::Ref<const VectorXd>& u) {
  auto* d = static_cast<ResidualDataContactGravityTorque*>(data.get());
  const auto q = x.head(state_->get_nq());
  d->r = u - pinocchio::computeStaticTorque(*pin_model_, d->pinocchio, q, d->contacts->fext);
}

void ResidualModelContactGravityTorque::calc(const std::shared_ptr<ResidualDataAbstract>& data,
                                             const Eigen::Ref<const VectorXd>& x) {
  // No control, no force: r = −g(q) (crocoddyl's convention for calc(x)).
  auto* d = static_cast<ResidualDataContactGravityTorque*>(data.get());
  const auto q = x.head(state_->get_nq());
  d->r = -pinocchio::computeGeneralizedGravity(*pin_model_, d->pinocchio, q);
}

void ResidualModelContactGravityTorque::calcDiff(
    const std::shared_ptr<ResidualDataAbstract>& data, const Eigen::Ref<const VectorXd>& x,
    const Eigen::Ref<const VectorXd>&) {
  auto* d = static_cast<ResidualDataContactGravityTorque*>(data.get());
  const std::size_t nv = state_->get_nv();
  const auto q = x.head(state_->get_nq());
  // ∂τ_g/∂q with the force fixed in its joint frame, then the world-fixed correction.
  pinocchio::computeStaticTorqueDerivatives(*pin_model_, d->pinocchio, q, d->contacts->fext,
                                            d->dtau_g_dq);
  if (world_aligned_) {
    d->dtau_g_dq += d->contact->dtau_dq;
  }
  const auto& contact = *d->contact;
  d->Rx.noalias() = contact.Jc.transpose() * contact.df_dx;
  d->Rx.leftCols(nv) -= d->dtau_g_dq;
  d->Ru.noalias() = contact.Jc.transpose() * contact.df_du;
  d->Ru.diagonal().array() += 1.0;
}

void ResidualModelContactGravityTorque::calcDiff(
    const std::shared_ptr<ResidualDataAbstract>& data, const Eigen::Ref<const VectorXd>& x) {
  auto* d = static_cast<ResidualDataContactGravityTorque*>(data.get());
  const std::size_t nv = state_->get_nv();
  const auto q = x.head(state_->get_nq());
  pinocchio::computeGeneralizedGravityDerivatives(*pin_model_, d->pinocchio, q, d->dtau_g_dq);
  d->Rx.leftCols(nv) = -d->dtau_g_dq;
  d->Rx.rightCols(nv).setZero();
}

std::shared_ptr<crocoddyl::ResidualDataAbstract> ResidualModelContactGravityTorque::createData(
    DataCollectorAbstract* const data) {
  return std::allocate_shared<ResidualDataContactGravityTorque>(
      Eigen::aligned_allocator<ResidualDataContactGravityTorque>(), this, data);
}

std::shared_ptr<crocoddyl::ResidualModelBase> ResidualModelContactGravityTorque::cloneAsDouble()
    const {
  return std::make_shared<ResidualModelContactGravityTorque>(*this);
}

std::shared_ptr<crocoddyl::ResidualModelBase> ResidualModelContactGravityTorque::cloneAsFloat()
    const {
  throw std::logic_error("ResidualModelContactGravityTorque exists in double precision only");
}

void ResidualModelContactGravityTorque::print(std::ostream& os) const {
  os << "ResidualModelContactGravityTorque {contact=" << contact_name_
     << ", world_aligned=" << (world_aligned_ ? "true" : "false") << "}";
}

ResidualDataContactGravityTorque::ResidualDataContactGravityTorque(
    ResidualModelContactGravityTorque* const model, crocoddyl::DataCollectorAbstract* const data)
    : Base(model, data),
      pinocchio(model->get_pinocchio()),
      dtau_g_dq(MatrixXd::Zero(model->get_state()->get_nv(), model->get_state()->get_nv())),
      nc(0) {
  auto* in_contact = dynamic_cast<crocoddyl::DataCollectorMultibodyInContact*>(data);
  if (in_contact == nullptr) {
    throw ModelError(
        "ResidualModelContactGravityTorque needs the data of a contact differential model "
        "(DifferentialActionModelContactFwdDynamics)");
  }
  contacts = in_contact->contacts;
  const auto it = contacts->contacts.find(model->get_contact_name());
  if (it == contacts->contacts.end()) {
    throw ModelError("ResidualModelContactGravityTorque: no contact named '" +
                                model->get_contact_name() + "'");
  }
  contact = it->second;
  nc = static_cast<std::size_t>(contact->Jc.rows());
}

// ---- ResidualModelFrameLinearVelocityWorld ----------------------------------------------------

ResidualModelFrameLinearVelocityWorld::ResidualModelFrameLinearVelocityWorld(
    std::shared_ptr<StateMultibody> state, pinocchio::FrameIndex frame_id, std::size_t nu)
    : Base(state, 3, nu, true, true, false),
      pin_model_(state->get_pinocchio()),
      frame_id_(frame_id) {
  if (frame_id >= static_cast<pinocchio::FrameIndex>(pin_model_->nframes)) {
    throw ConfigError("ResidualModelFrameLinearVelocityWorld: frame_id out of range");
  }
}

void ResidualModelFrameLinearVelocityWorld::calc(
    const std::shared_ptr<ResidualDataAbstract>& data, const Eigen::Ref<const VectorXd>&,
    const Eigen::Ref<const VectorXd>&) {
  // The differential model has run forward kinematics with (q, v) in the shared data.
  auto* d = static_cast<ResidualDataFrameLinearVelocityWorld*>(data.get());
  d->r = pinocchio::getFrameVelocity(*pin_model_, *d->shared_pinocchio, frame_id_,
                                     pinocchio::LOCAL_WORLD_ALIGNED)
             .linear();
}

void ResidualModelFrameLinearVelocityWorld::calc(
    const std::shared_ptr<ResidualDataAbstract>& data, const Eigen::Ref<const VectorXd>& x) {
  calc(data, x, unone_);
}

void ResidualModelFrameLinearVelocityWorld::calcDiff(
    const std::shared_ptr<ResidualDataAbstract>& data, const Eigen::Ref<const VectorXd>& x,
    const Eigen::Ref<const VectorXd>&) {
  auto* d = static_cast<ResidualDataFrameLinearVelocityWorld*>(data.get());
  const std::size_t nq = state_->get_nq();
  const std::size_t nv = state_->get_nv();
  pinocchio::Data& pd = d->pinocchio;
  pinocchio::computeForwardKinematicsDerivatives(*pin_model_, pd, x.head(nq), x.segment(nq, nv),
                                                 d->zero_a);
  pinocchio::getFrameVelocityDerivatives(*pin_model_, pd, frame_id_, pinocchio::LOCAL, d->dv_dq,
                                         d->dv_dv);
  const Eigen::Matrix3d rotation = pinocchio::updateFramePlacement(*pin_model_, pd, frame_id_).rotation();
  const Eigen::Vector3d v_local =
      pinocchio::getFrameVelocity(*pin_model_, pd, frame_id_, pinocchio::LOCAL).linear();
  d->dvl_dq.noalias() = -pinocchio::skew(v_local) * d->dv_dv.bottomRows<3>();
  d->dvl_dq += d->dv_dq.topRows<3>();
  d->Rx.leftCols(nv).noalias() = rotation * d->dvl_dq;
  d->Rx.rightCols(nv).noalias() = rotation * d->dv_dv.topRows<3>();
}

void ResidualModelFrameLinearVelocityWorld::calcDiff(
    const std::shared_ptr<ResidualDataAbstract>& data, const Eigen::Ref<const VectorXd>& x) {
  calcDiff(data, x, unone_);
}

std::shared_ptr<crocoddyl::ResidualDataAbstract> ResidualModelFrameLinearVelocityWorld::createData(
    DataCollectorAbstract* const data) {
  return std::allocate_shared<ResidualDataFrameLinearVelocityWorld>(
      Eigen::aligned_allocator<ResidualDataFrameLinearVelocityWorld>(), this, data);
}

std::shared_ptr<crocoddyl::ResidualModelBase>
ResidualModelFrameLinearVelocityWorld::cloneAsDouble() const {
  return std::make_shared<ResidualModelFrameLinearVelocityWorld>(*this);
}

std::shared_ptr<crocoddyl::ResidualModelBase>
ResidualModelFrameLinearVelocityWorld::cloneAsFloat() const {
  throw std::logic_error("ResidualModelFrameLinearVelocityWorld exists in double precision only");
}

void ResidualModelFrameLinearVelocityWorld::print(std::ostream& os) const {
  os << "ResidualModelFrameLinearVelocityWorld {frame=" << pin_model_->frames[frame_id_].name
     << "}";
}

ResidualDataFrameLinearVelocityWorld::ResidualDataFrameLinearVelocityWorld(
    ResidualModelFrameLinearVelocityWorld* const model,
    crocoddyl::DataCollectorAbstract* const data)
    : Base(model, data),
      shared_pinocchio(nullptr),
      pinocchio(*static_cast<crocoddyl::StateMultibody*>(model->get_state().get())
                     ->get_pinocchio()),
      dv_dq(Matrix6xd::Zero(6, model->get_state()->get_nv())),
      dv_dv(Matrix6xd::Zero(6, model->get_state()->get_nv())),
      dvl_dq(Eigen::Matrix<double, 3, Eigen::Dynamic>::Zero(3, model->get_state()->get_nv())),
      zero_a(VectorXd::Zero(model->get_state()->get_nv())) {
  auto* multibody = dynamic_cast<crocoddyl::DataCollectorMultibody*>(data);
  if (multibody == nullptr) {
    throw ModelError(
        "ResidualModelFrameLinearVelocityWorld needs the data of a multibody differential model");
  }
  shared_pinocchio = multibody->pinocchio;
}

// ---- ResidualModelConstraintRows --------------------------------------------------------------

ResidualModelConstraintRows::ResidualModelConstraintRows(
    std::shared_ptr<crocoddyl::StateAbstract> state, std::size_t nu,
    const Eigen::MatrixXd& state_matrix, const Eigen::VectorXd& control_scale, bool control)
    : Base(state, ConstraintRows(state_matrix, control_scale, state->get_nx(), nu, control).ng(),
           nu, true, true, control),
      rows_(state_matrix, control_scale, state->get_nx(), nu, control) {
  if (state->get_nx() != state->get_ndx()) {
    throw ModelError("ResidualModelConstraintRows needs a vector state (nx == ndx)");
  }
  if (rows_.n_state() == 0) {
    throw ConfigError("ResidualModelConstraintRows: the constraint matrix has no rows");
  }
}

void ResidualModelConstraintRows::calc(const std::shared_ptr<ResidualDataAbstract>& data,
                                       const Eigen::Ref<const VectorXd>& x,
                                       const Eigen::Ref<const VectorXd>& u) {
  rows_.calc(data->r, x, u);
}

void ResidualModelConstraintRows::calc(const std::shared_ptr<ResidualDataAbstract>& data,
                                       const Eigen::Ref<const VectorXd>& x) {
  rows_.calc(data->r, x);
}

void ResidualModelConstraintRows::calcDiff(const std::shared_ptr<ResidualDataAbstract>& data,
                                           const Eigen::Ref<const VectorXd>&,
                                           const Eigen::Ref<const VectorXd>&) {
  rows_.calcDiff(data->Rx, data->Ru);
}

void ResidualModelConstraintRows::calcDiff(const std::shared_ptr<ResidualDataAbstract>& data,
                                           const Eigen::Ref<const VectorXd>&) {
  rows_.calcDiff(data->Rx, data->Ru);
}

std::shared_ptr<crocoddyl::ResidualModelBase> ResidualModelConstraintRows::cloneAsDouble() const {
  return std::make_shared<ResidualModelConstraintRows>(*this);
}

std::shared_ptr<crocoddyl::ResidualModelBase> ResidualModelConstraintRows::cloneAsFloat() const {
  throw std::logic_error("ResidualModelConstraintRows exists in double precision only");
}

void ResidualModelConstraintRows::print(std::ostream& os) const {
  os << "ResidualModelConstraintRows {state rows=" << rows_.n_state()
     << ", control rows=" << (rows_.control ? rows_.nu : 0) << "}";
}

}  // namespace ffmpc
