// Force-feedback action model: implementation and Python bindings (see soft_contact.hpp).
// Every step mirrors ffmpc_core/soft_contact.py line by line, so that the Python model can be
// read as the specification of this code.
#include "soft_contact.hpp"

#include <cmath>
#include <iostream>
#include <limits>
#include <sstream>

#include <boost/python.hpp>
#include <eigenpy/eigenpy.hpp>
#include <pinocchio/algorithm/aba-derivatives.hpp>
#include <pinocchio/algorithm/aba.hpp>
#include <pinocchio/algorithm/frames-derivatives.hpp>
#include <pinocchio/algorithm/frames.hpp>
#include <pinocchio/algorithm/kinematics-derivatives.hpp>
#include <pinocchio/algorithm/kinematics.hpp>
#include <pinocchio/algorithm/rnea-derivatives.hpp>
#include <pinocchio/algorithm/rnea.hpp>
#include <pinocchio/spatial/explog.hpp>

#include "errors.hpp"

namespace ffmpc {

namespace {

const char* const kTermNames[kNumTerms] = {
    "posture",    "joint_velocity", "torque",      "ee_position",        "ee_velocity",
    "force",      "force_rate",     "state_limit", "ee_rotation", "ee_angular_velocity"};

/// [a]x, the cross-product matrix ([a]x b = a x b).
inline Eigen::Matrix3d skew(const Eigen::Vector3d& a) {
  Eigen::Matrix3d s;
  s << 0.0, -a[2], a[1], a[2], 0.0, -a[0], -a[1], a[0], 0.0;
  return s;
}

std::size_t term_index(const std::string& name) {
  for (std::size_t k = 0; k < kNumTerms; ++k) {
    if (name == kTermNames[k]) return k;
  }
  std::ostringstream msg;
  msg << "unknown cost term '" << name << "'; choose one of (posture, joint_velocity, torque, "
      << "ee_position, ee_velocity, force, force_rate, state_limit, ee_rotation, "
      << "ee_angular_velocity)";
  throw ConfigError(msg.str());
}

std::string format(const VectorXd& v) {
  std::ostringstream s;
  s << "[" << v.transpose() << "]";
  return s.str();
}

/// ``value`` as a vector of ``n`` entries (size 1 broadcasts when ``broadcast``), all finite.
template <class Error>
VectorXd finite_vector(const VectorXd& value, std::size_t n, const char* name, bool broadcast) {
  VectorXd out;
  if (static_cast<std::size_t>(value.size()) == n) {
    out = value;
  } else if (broadcast && value.size() == 1) {
    out = VectorXd::Constant(n, value[0]);
  } else {
    std::ostringstream msg;
    msg << name << " must have " << n << " entries, got " << value.size();
    throw Error(msg.str());
  }
  if (!out.allFinite()) throw Error(std::string(name) + " must be finite, got " + format(out));
  return out;
}

template <class Error>
VectorXd non_negative_vector(const VectorXd& value, std::size_t n, const char* name,
                             bool broadcast) {
  VectorXd out = finite_vector<Error>(value, n, name, broadcast);
  if ((out.array() < 0.0).any()) {
    throw Error(std::string(name) + " must be non-negative, got " + format(out));
  }
  return out;
}

template <class Error>
void check_weight(double c, const std::string& name) {
  if (!std::isfinite(c) || c < 0.0) {
    std::ostringstream msg;
    msg << name << " must be finite and non-negative, got " << c;
    throw Error(msg.str());
  }
}

}  // namespace

// ======================================================================= dynamics data
SoftContactDynamicsData::SoftContactDynamicsData(const pinocchio::Model& model, std::size_t nc)
    : pinocchio(model),
      pinocchio_aba(model),
      pinocchio_static(model),
      fext(model.njoints, pinocchio::Force::Zero()),
      force_frame(Eigen::Vector3d::Zero()),
      force_local(Eigen::Vector3d::Zero()),
      rotation(Eigen::Matrix3d::Identity()),
      position(Eigen::Vector3d::Zero()),
      linear_velocity_local(Eigen::Vector3d::Zero()),
      angular_velocity_local(Eigen::Vector3d::Zero()),
      classical_acceleration_local(Eigen::Vector3d::Zero()),
      ee_velocity(Eigen::Vector3d::Zero()),
      frame_velocity(Eigen::Vector3d::Zero()),
      frame_acceleration(Eigen::Vector3d::Zero()),
      ddq(VectorXd::Zero(model.nv)),
      force_rate(VectorXd::Zero(nc)),
      gravity_compensation(VectorXd::Zero(model.nv)),
      ddq_dxu(MatrixXd::Zero(model.nv, 3 * model.nv + nc)),
      force_rate_dxu(MatrixXd::Zero(nc, 3 * model.nv + nc)),
      frame_velocity_dxu(Matrix3xd::Zero(3, 3 * model.nv + nc)),
      frame_acceleration_dxu(Matrix3xd::Zero(3, 3 * model.nv + nc)),
      local_acceleration_dxu(Matrix3xd::Zero(3, 3 * model.nv + nc)),
      velocity_dq(Matrix6xd::Zero(6, model.nv)),
      jacobian(Matrix6xd::Zero(6, model.nv)),
      acceleration_dq(Matrix6xd::Zero(6, model.nv)),
      acceleration_dv(Matrix6xd::Zero(6, model.nv)),
      minv(MatrixXd::Zero(model.nv, model.nv)),
      contact_jacobian(MatrixXd::Zero(nc, model.nv)),
      position_dq(Matrix3xd::Zero(3, model.nv)),
      ee_velocity_dqv(Matrix3xd::Zero(3, 2 * model.nv)),
      gravity_compensation_dq(MatrixXd::Zero(model.nv, model.nv)),
      gravity_compensation_dforce(MatrixXd::Zero(model.nv, nc)),
      minv_jlin_t(Eigen::Matrix<double, Eigen::Dynamic, 3>::Zero(model.nv, 3)),
      tmp_3nv(Matrix3xd::Zero(3, model.nv)),
      local_velocity_dqv(Matrix3xd::Zero(3, 2 * model.nv)),
      tmp_3x2nv(Matrix3xd::Zero(3, 2 * model.nv)),
      zero_nv(VectorXd::Zero(model.nv)) {}

// ======================================================================= dynamics
SoftContactDynamics::SoftContactDynamics(const pinocchio::Model& model, std::size_t frame_id,
                                         std::size_t nc, bool world_aligned,
                                         std::size_t normal_axis)
    : model_(model),
      nv_(model.nv),
      nc_(nc),
      frame_id_(frame_id),
      parent_joint_(0),
      normal_axis_(normal_axis),
      world_aligned_(world_aligned) {
  if (model.nq != model.nv) {
    throw ConfigError("the soft-contact state (q, v, lambda) is a vector state and needs nq == nv");
  }
  if (frame_id == 0 || frame_id >= model.frames.size()) {
    throw ConfigError("bad contact frame id " + std::to_string(frame_id));
  }
  if (nc != 1 && nc != 3) throw ConfigError("contact dimension must be 1 or 3");
  if (normal_axis > 2) throw ConfigError("normal_axis must be 0, 1 or 2");
  const pinocchio::Frame& frame = model.frames[frame_id];
  parent_joint_ = frame.parentJoint;
  // A force f (contact-frame axes, at the frame origin) as a spatial force in the joint frame.
  const Eigen::Matrix3d jRf = frame.placement.rotation();
  const Eigen::Vector3d jpf = frame.placement.translation();
  force_to_joint_.topRows<3>() = jRf;
  force_to_joint_.bottomRows<3>() = skew(jpf) * jRf;
  stiffness_ = VectorXd::Zero(nc);
  damping_ = VectorXd::Zero(nc);
}

void SoftContactDynamics::set_contact_parameters(const VectorXd& stiffness,
                                                 const VectorXd& damping) {
  VectorXd K = non_negative_vector<ConfigError>(stiffness, nc_, "stiffness", false);
  VectorXd B = non_negative_vector<ConfigError>(damping, nc_, "damping", false);
  stiffness_ = K;
  damping_ = B;
}

void SoftContactDynamics::set_external_force(SoftContactDynamicsData& d,
                                             const Eigen::Ref<const VectorXd>& force) const {
  d.force_frame.setZero();
  for (std::size_t i = 0; i < nc_; ++i) d.force_frame[row(i)] = force[i];
  if (world_aligned_) {
    d.force_local.noalias() = d.rotation.transpose() * d.force_frame;
  } else {
    d.force_local = d.force_frame;
  }
  d.fext[parent_joint_].toVector().noalias() = force_to_joint_ * d.force_local;
}

void SoftContactDynamics::read_frame_kinematics(SoftContactDynamicsData& d) const {
  const pinocchio::SE3& oMf = pinocchio::updateFramePlacement(model_, d.pinocchio, frame_id_);
  d.rotation = oMf.rotation();
  d.position = oMf.translation();
  const pinocchio::Motion vel =
      pinocchio::getFrameVelocity(model_, d.pinocchio, frame_id_, pinocchio::LOCAL);
  d.linear_velocity_local = vel.linear();
  d.angular_velocity_local = vel.angular();
  d.ee_velocity.noalias() = d.rotation * d.linear_velocity_local;
}

void SoftContactDynamics::calc(SoftContactDynamicsData& d, const Eigen::Ref<const VectorXd>& q,
                               const Eigen::Ref<const VectorXd>& v,
                               const Eigen::Ref<const VectorXd>& force,
                               const Eigen::Ref<const VectorXd>& tau) const {
  if (world_aligned_) {
    pinocchio::forwardKinematics(model_, d.pinocchio, q);
    d.rotation = pinocchio::updateFramePlacement(model_, d.pinocchio, frame_id_).rotation();
  }
  set_external_force(d, force);
  // WORLD convention, in its own data: calc_diff reuses this pass (the derivative overload
  // without q, v, tau), which saves a third of the ABA derivatives' cost.
  d.ddq = pinocchio::aba(model_, d.pinocchio_aba, q, v, tau, d.fext, pinocchio::Convention::WORLD);
  pinocchio::forwardKinematics(model_, d.pinocchio, q, v, d.ddq);
  read_frame_kinematics(d);
  d.classical_acceleration_local =
      pinocchio::getFrameClassicalAcceleration(model_, d.pinocchio, frame_id_, pinocchio::LOCAL)
          .linear();
  if (world_aligned_) {
    d.frame_velocity = d.ee_velocity;
    d.frame_acceleration.noalias() = d.rotation * d.classical_acceleration_local;
  } else {
    d.frame_velocity = d.linear_velocity_local;
    d.frame_acceleration = d.classical_acceleration_local;
  }
  for (std::size_t i = 0; i < nc_; ++i) {
    d.force_rate[i] =
        -stiffness_[i] * d.frame_velocity[row(i)] - damping_[i] * d.frame_acceleration[row(i)];
  }
}

void SoftContactDynamics::calc_kinematics(SoftContactDynamicsData& d,
                                          const Eigen::Ref<const VectorXd>& q,
                                          const Eigen::Ref<const VectorXd>& v) const {
  pinocchio::forwardKinematics(model_, d.pinocchio, q, v);
  read_frame_kinematics(d);
}

void SoftContactDynamics::calc_gravity_compensation(SoftContactDynamicsData& d,
                                                    const Eigen::Ref<const VectorXd>& q) const {
  d.gravity_compensation = pinocchio::computeStaticTorque(model_, d.pinocchio_static, q, d.fext);
}

void SoftContactDynamics::calc_diff(SoftContactDynamicsData& d,
                                    const Eigen::Ref<const VectorXd>& q,
                                    const Eigen::Ref<const VectorXd>& v,
                                    const Eigen::Ref<const VectorXd>& tau) const {
  const std::size_t nv = nv_, ndx = 2 * nv_ + nc_;
  pinocchio::Data& pd = d.pinocchio;
  pinocchio::Data& pa = d.pinocchio_aba;  // holds calc's WORLD-convention ABA at (q, v, tau)
  pinocchio::computeABADerivatives(model_, pa, d.fext);
  d.ddq_dxu.leftCols(nv) = pa.ddq_dq;
  d.ddq_dxu.middleCols(nv, nv) = pa.ddq_dv;
  // Only the upper triangle of M^-1 is filled.
  d.minv.triangularView<Eigen::Upper>() = pa.Minv;
  d.minv.triangularView<Eigen::StrictlyLower>() = pa.Minv.transpose();
  d.ddq_dxu.middleCols(ndx, nv) = d.minv;
  pinocchio::computeForwardKinematicsDerivatives(model_, pd, q, v, d.ddq);
  pinocchio::getFrameAccelerationDerivatives(model_, pd, frame_id_, pinocchio::LOCAL,
                                             d.velocity_dq, d.acceleration_dq,
                                             d.acceleration_dv, d.jacobian);
  const auto Jl = d.jacobian.topRows<3>();
  const auto Ja = d.jacobian.bottomRows<3>();
  const Eigen::Matrix3d& R = d.rotation;
  d.minv_jlin_t.noalias() = d.minv.lazyProduct(Jl.transpose());

  // Eq 22, dq''/dlambda = M^-1 J^T; world-fixed force: dq''/dq += M^-1 J_lin^T [f_local]x J_ang.
  auto ddq_dforce = d.ddq_dxu.middleCols(2 * nv, nc_);
  if (world_aligned_) {
    d.tmp_3nv.noalias() = skew(d.force_local) * Ja;
    d.ddq_dxu.leftCols(nv).noalias() += d.minv_jlin_t.lazyProduct(d.tmp_3nv);
    for (std::size_t i = 0; i < nc_; ++i) {
      ddq_dforce.col(i).noalias() = d.minv_jlin_t * R.row(row(i)).transpose();
      d.contact_jacobian.row(i).noalias() = R.row(row(i)) * Jl;
    }
  } else {
    for (std::size_t i = 0; i < nc_; ++i) {
      ddq_dforce.col(i) = d.minv_jlin_t.col(row(i));
      d.contact_jacobian.row(i) = Jl.row(row(i));
    }
  }
  d.position_dq.noalias() = R * Jl;

  // Local axes: velocity v_lin and classical acceleration c = a_lin + w x v_lin.
  Eigen::Matrix<double, 3, 6> C;
  C.leftCols<3>() = skew(d.angular_velocity_local);
  const Eigen::Matrix3d S_v = skew(d.linear_velocity_local);
  C.rightCols<3>() = -S_v;
  d.local_velocity_dqv.leftCols(nv) = d.velocity_dq.topRows<3>();
  d.local_velocity_dqv.rightCols(nv) = Jl;
  Matrix3xd& dacc = d.local_acceleration_dxu;
  dacc.noalias() = Jl.lazyProduct(d.ddq_dxu);  // chain rule through q'' (eq 23, dp''/dq'' = J)
  dacc.leftCols(nv) += d.acceleration_dq.topRows<3>();
  dacc.middleCols(nv, nv) += d.acceleration_dv.topRows<3>();
  dacc.leftCols(nv).noalias() += C.lazyProduct(d.velocity_dq);
  dacc.middleCols(nv, nv).noalias() += C.lazyProduct(d.jacobian);

  // World-aligned linear velocity, d(R v) = R (dv - [v]x J_ang dq).
  d.tmp_3nv.noalias() = S_v * Ja;
  d.ee_velocity_dqv = d.local_velocity_dqv;
  d.ee_velocity_dqv.leftCols(nv) -= d.tmp_3nv;
  d.tmp_3x2nv = d.ee_velocity_dqv;
  d.ee_velocity_dqv.noalias() = R.lazyProduct(d.tmp_3x2nv);

  if (world_aligned_) {
    d.frame_velocity_dxu.leftCols(2 * nv) = d.ee_velocity_dqv;
    d.tmp_3nv.noalias() = skew(d.classical_acceleration_local) * Ja;
    dacc.leftCols(nv) -= d.tmp_3nv;
    d.frame_acceleration_dxu.noalias() = R.lazyProduct(dacc);
  } else {
    d.frame_velocity_dxu.leftCols(2 * nv) = d.local_velocity_dqv;
    d.frame_acceleration_dxu = dacc;
  }

  // Eq 23a-d: dlambda' = -K dp' - B dp'' (rows matching lambda), all columns at once.
  for (std::size_t i = 0; i < nc_; ++i) {
    d.force_rate_dxu.row(i) = -stiffness_[i] * d.frame_velocity_dxu.row(row(i)) -
                              damping_[i] * d.frame_acceleration_dxu.row(row(i));
  }
}

void SoftContactDynamics::calc_kinematics_diff(SoftContactDynamicsData& d,
                                               const Eigen::Ref<const VectorXd>& q,
                                               const Eigen::Ref<const VectorXd>& v) const {
  const std::size_t nv = nv_;
  pinocchio::computeForwardKinematicsDerivatives(model_, d.pinocchio, q, v, d.zero_nv);
  pinocchio::getFrameVelocityDerivatives(model_, d.pinocchio, frame_id_, pinocchio::LOCAL,
                                         d.velocity_dq, d.jacobian);
  const auto Jl = d.jacobian.topRows<3>();
  const auto Ja = d.jacobian.bottomRows<3>();
  const Eigen::Matrix3d& R = d.rotation;
  d.position_dq.noalias() = R * Jl;
  d.ee_velocity_dqv.leftCols(nv) = d.velocity_dq.topRows<3>();
  d.ee_velocity_dqv.rightCols(nv) = Jl;
  d.tmp_3nv.noalias() = skew(d.linear_velocity_local) * Ja;
  d.ee_velocity_dqv.leftCols(nv) -= d.tmp_3nv;
  d.tmp_3x2nv = d.ee_velocity_dqv;
  d.ee_velocity_dqv.noalias() = R.lazyProduct(d.tmp_3x2nv);
}

void SoftContactDynamics::calc_gravity_compensation_diff(
    SoftContactDynamicsData& d, const Eigen::Ref<const VectorXd>& q) const {
  d.gravity_compensation_dq.setZero();
  pinocchio::computeStaticTorqueDerivatives(model_, d.pinocchio_static, q, d.fext,
                                            d.gravity_compensation_dq);
  if (world_aligned_) {
    // tau_g contains -J_lin^T R^T f_w; d(R^T f_w) = [R^T f_w]x J_ang dq.
    d.tmp_3nv.noalias() = skew(d.force_local) * d.jacobian.bottomRows<3>();
    d.gravity_compensation_dq.noalias() -= d.jacobian.topRows<3>().transpose().lazyProduct(d.tmp_3nv);
  }
  d.gravity_compensation_dforce = -d.contact_jacobian.transpose();
}

// ======================================================================= action model
IntegratedActionModelSoftContact::IntegratedActionModelSoftContact(
    const pinocchio::Model& model, std::size_t frame_id, std::size_t nc, bool world_aligned,
    std::size_t normal_axis, double dt, bool terminal, const Eigen::MatrixXd& constraint_matrix,
    const Eigen::VectorXd& control_scale)
    : Base(std::make_shared<crocoddyl::StateVector>(2 * model.nv + nc), model.nv,
           5 * model.nv + 12 + 2 * nc,
           ConstraintRows(constraint_matrix, control_scale, 2 * model.nv + nc, model.nv, !terminal)
               .ng(),
           0,
           static_cast<std::size_t>(constraint_matrix.rows()), 0),
      dynamics_(model, frame_id, nc, world_aligned, normal_axis),
      nv_(model.nv),
      nc_(nc),
      ndx_(2 * model.nv + nc),
      dt_(dt),
      terminal_(terminal),
      in_contact_(true),
      constraint_rows_(constraint_matrix, control_scale, 2 * model.nv + nc, model.nv, !terminal) {
  if (!std::isfinite(dt) || dt < 0.0 || (dt <= 0.0 && !terminal)) {
    std::ostringstream msg;
    msg << "dt must be positive and finite, got " << dt;
    throw ConfigError(msg.str());
  }
  size_ = {nv_, nv_, nv_, 3, 3, nc_, nc_, 2 * nv_, 3, 3};
  std::size_t offset = 0;
  for (std::size_t k = 0; k < kNumTerms; ++k) {
    offset_[k] = offset;
    offset += size_[k];
    c_[k] = 0.0;
    diag_[k] = VectorXd::Ones(size_[k]);
  }
  default_ee_position_diag_ = VectorXd::Ones(3);
  q_reference_ = VectorXd::Zero(nv_);
  ee_position_reference_ = VectorXd::Zero(3);
  force_reference_ = VectorXd::Zero(nc_);
  rotation_reference_.setIdentity();
  nominal_stiffness_ = VectorXd::Zero(nc_);
  nominal_damping_ = VectorXd::Zero(nc_);
  state_limit_lower_ = VectorXd::Constant(2 * nv_, -std::numeric_limits<double>::infinity());
  state_limit_upper_ = VectorXd::Constant(2 * nv_, std::numeric_limits<double>::infinity());
  w_running_ = VectorXd::Zero(nr_);
  w_state_ = VectorXd::Zero(nr_);
  sqrt_w_running_ = VectorXd::Zero(nr_);
  sqrt_w_state_ = VectorXd::Zero(nr_);
  update_weights();
}

void IntegratedActionModelSoftContact::update_weights() {
  for (std::size_t k = 0; k < kNumTerms; ++k) {
    const double c = (k == FORCE && !in_contact_) ? 0.0 : c_[k];
    const auto w = (c * diag_[k]).eval();
    w_running_.segment(offset_[k], size_[k]) = dt_ * w;
    if (k == TORQUE || k == FORCE_RATE) {
      w_state_.segment(offset_[k], size_[k]).setZero();
    } else {
      w_state_.segment(offset_[k], size_[k]) = w;
    }
  }
  sqrt_w_running_ = w_running_.cwiseSqrt();
  sqrt_w_state_ = w_state_.cwiseSqrt();
}

void IntegratedActionModelSoftContact::set_weight(const std::string& name, double value) {
  const std::size_t k = term_index(name);
  check_weight<ConfigError>(value, "weight " + name);
  c_[k] = value;
  update_weights();
}

double IntegratedActionModelSoftContact::weight(const std::string& name) const {
  return c_[term_index(name)];
}

void IntegratedActionModelSoftContact::set_activation(const std::string& name,
                                                      const VectorXd& diag) {
  const std::size_t k = term_index(name);
  VectorXd q = non_negative_vector<ConfigError>(diag, size_[k], (name + "_diag").c_str(), false);
  diag_[k] = q;
  if (k == EE_POSITION) default_ee_position_diag_ = q;
  update_weights();
}

const VectorXd& IntegratedActionModelSoftContact::activation(const std::string& name) const {
  return diag_[term_index(name)];
}

void IntegratedActionModelSoftContact::set_reference_values(
    const VectorXd& ee_position, const VectorXd& force, double ee_position_weight,
    double force_weight, bool in_contact, const VectorXd& posture,
    const VectorXd& ee_position_diag) {
  // Validate everything first: an InputError changes nothing.
  const VectorXd p = finite_vector<InputError>(ee_position, 3, "ee_position", false);
  const VectorXd f = finite_vector<InputError>(force, nc_, "force", false);
  if (posture.size() != 0) finite_vector<InputError>(posture, nv_, "posture", false);
  const bool has_diag = ee_position_diag.size() != 0;
  if (has_diag) non_negative_vector<InputError>(ee_position_diag, 3, "ee_position_diag", false);
  check_weight<InputError>(ee_position_weight, "ee_position_weight");
  check_weight<InputError>(force_weight, "force_weight");
  ee_position_reference_ = p;
  force_reference_ = f;
  if (posture.size() != 0) q_reference_ = posture;
  const VectorXd& q4 = has_diag ? ee_position_diag : default_ee_position_diag_;
  // The weight vectors are rebuilt only when a weight, Q4 or the contact flag changes.
  const bool weights_changed = c_[EE_POSITION] != ee_position_weight ||
                               c_[FORCE] != force_weight || diag_[EE_POSITION] != q4;
  c_[EE_POSITION] = ee_position_weight;
  c_[FORCE] = force_weight;
  diag_[EE_POSITION] = q4;
  if (in_contact != in_contact_) {
    set_in_contact(in_contact);  // updates the weights
  } else if (weights_changed) {
    update_weights();
  }
}

void IntegratedActionModelSoftContact::set_in_contact(bool in_contact) {
  in_contact_ = in_contact;
  if (in_contact_) {
    dynamics_.set_contact_parameters(nominal_stiffness_, nominal_damping_);
  } else {
    dynamics_.set_contact_parameters(VectorXd::Zero(nc_), VectorXd::Zero(nc_));
  }
  update_weights();
}

void IntegratedActionModelSoftContact::set_contact_parameters(const VectorXd& stiffness,
                                                              const VectorXd& damping) {
  VectorXd K = non_negative_vector<ConfigError>(stiffness, nc_, "stiffness", false);
  VectorXd B = non_negative_vector<ConfigError>(damping, nc_, "damping", false);
  nominal_stiffness_ = K;
  nominal_damping_ = B;
  set_in_contact(in_contact_);
}

void IntegratedActionModelSoftContact::set_q_reference(const VectorXd& q_reference) {
  q_reference_ = finite_vector<ConfigError>(q_reference, nv_, "q_reference", false);
}

void IntegratedActionModelSoftContact::set_rotation_reference(const Eigen::Matrix3d& rotation) {
  if (!rotation.allFinite() ||
      !(rotation.transpose() * rotation).isApprox(Eigen::Matrix3d::Identity(), 1e-9) ||
      std::abs(rotation.determinant() - 1.0) > 1e-9) {
    std::ostringstream msg;
    msg << "rotation_reference must be a rotation matrix, got [" << rotation << "]";
    throw ConfigError(msg.str());
  }
  rotation_reference_ = rotation;
}

void IntegratedActionModelSoftContact::set_state_limit_bounds(const VectorXd& lower,
                                                              const VectorXd& upper) {
  const std::size_t n = 2 * nv_;
  if (static_cast<std::size_t>(lower.size()) != n || static_cast<std::size_t>(upper.size()) != n) {
    std::ostringstream msg;
    msg << "state-limit bounds must have " << n << " entries, got " << lower.size() << ", "
        << upper.size();
    throw ConfigError(msg.str());
  }
  for (std::size_t i = 0; i < n; ++i) {
    if (std::isnan(lower[i]) || std::isnan(upper[i]) || lower[i] > upper[i]) {
      throw ConfigError("state-limit bounds must be ordered and not NaN, got " + format(lower) +
                        ", " + format(upper));
    }
  }
  state_limit_lower_ = lower;
  state_limit_upper_ = upper;
}

void IntegratedActionModelSoftContact::state_limit_jacobian(
    IntegratedActionDataSoftContact& d, const Eigen::Ref<const VectorXd>& x) const {
  const std::size_t offset = offset_[STATE_LIMIT];
  for (std::size_t i = 0; i < 2 * nv_; ++i) {
    const double xi = x[i];
    d.Rx(offset + i, i) = (xi <= state_limit_lower_[i] || xi >= state_limit_upper_[i]) ? 1.0 : 0.0;
  }
}

void IntegratedActionModelSoftContact::add_state_hessian(IntegratedActionDataSoftContact& d,
                                                         const VectorXd& w) const {
  // Lxx of the state terms: posture (d/dq = I), joint velocity (d/dv = I), force
  // (d/dlambda = I) are diagonal; ee position (3 x nv, on q) and ee velocity (3 x 2nv, on q, v)
  // are three rank-one updates each.
  const std::size_t nv = nv_, nc = nc_;
  d.Lxx.setZero();
  d.Lxx.diagonal().head(nv) = w.segment(offset_[POSTURE], nv);
  d.Lxx.diagonal().segment(nv, nv) = w.segment(offset_[JOINT_VELOCITY], nv);
  d.Lxx.diagonal().tail(nc) = w.segment(offset_[FORCE], nc);
  // Joint-limit barrier: diagonal, w on the entries at or beyond a bound (Rx holds 1 there).
  d.Lxx.diagonal().head(2 * nv) += w.segment(offset_[STATE_LIMIT], 2 * nv).cwiseProduct(
      d.Rx.block(offset_[STATE_LIMIT], 0, 2 * nv, 2 * nv).diagonal());
  for (std::size_t i = 0; i < 3; ++i) {
    const double wp = w[offset_[EE_POSITION] + i];
    const auto rp = d.Rx.row(offset_[EE_POSITION] + i).head(nv);
    d.Lxx.topLeftCorner(nv, nv).noalias() += (wp * rp.transpose()) * rp;
    const double wv = w[offset_[EE_VELOCITY] + i];
    const auto rv = d.Rx.row(offset_[EE_VELOCITY] + i).head(2 * nv);
    d.Lxx.topLeftCorner(2 * nv, 2 * nv).noalias() += (wv * rv.transpose()) * rv;
  }
  // Orientation (3 x nv, on q) and angular velocity (3 x 2nv, on q, v): skipped at zero weight.
  for (std::size_t i = 0; i < 3; ++i) {
    const double wr = w[offset_[EE_ROTATION] + i];
    if (wr != 0.0) {
      const auto rr = d.Rx.row(offset_[EE_ROTATION] + i).head(nv);
      d.Lxx.topLeftCorner(nv, nv).noalias() += (wr * rr.transpose()) * rr;
    }
    const double wa = w[offset_[EE_ANGULAR_VELOCITY] + i];
    if (wa != 0.0) {
      const auto ra = d.Rx.row(offset_[EE_ANGULAR_VELOCITY] + i).head(2 * nv);
      d.Lxx.topLeftCorner(2 * nv, 2 * nv).noalias() += (wa * ra.transpose()) * ra;
    }
  }
}

void IntegratedActionModelSoftContact::orientation_jacobians(
    IntegratedActionDataSoftContact& d) const {
  // d log3(R_bar^T R) = Jlog3(R_bar^T R) J_ang dq (J LOCAL), as crocoddyl's FrameRotation;
  // the LOCAL angular velocity's partials are the angular rows of the twist's.
  const std::size_t nv = nv_;
  const SoftContactDynamicsData& dd = d.dynamics;
  d.relative_rotation.noalias() = rotation_reference_.transpose() * dd.rotation;
  pinocchio::Jlog3(d.relative_rotation, d.jlog);
  d.Rx.block(offset_[EE_ROTATION], 0, 3, nv).noalias() = d.jlog * dd.jacobian.bottomRows<3>();
  d.Rx.block(offset_[EE_ANGULAR_VELOCITY], 0, 3, nv) = dd.velocity_dq.bottomRows<3>();
  d.Rx.block(offset_[EE_ANGULAR_VELOCITY], nv, 3, nv) = dd.jacobian.bottomRows<3>();
}

void IntegratedActionModelSoftContact::calc(const std::shared_ptr<ActionDataAbstract>& data,
                                            const Eigen::Ref<const VectorXd>& x,
                                            const Eigen::Ref<const VectorXd>& u) {
  check_size(x.size(), state_->get_nx(), "x");
  if (terminal_) {
    calc(data, x);
    return;
  }
  check_size(u.size(), nu_, "u");
  IntegratedActionDataSoftContact* d = static_cast<IntegratedActionDataSoftContact*>(data.get());
  SoftContactDynamicsData& dd = d->dynamics;
  const std::size_t nv = nv_, nc = nc_;
  const auto q = x.head(nv);
  const auto v = x.segment(nv, nv);
  const auto lam = x.tail(nc);
  VectorXd& r = d->residual;
  state_residuals(r, x);
  dynamics_.calc(dd, q, v, lam, u);
  dynamics_.calc_gravity_compensation(dd, q);
  r.segment(offset_[TORQUE], nv) = u - dd.gravity_compensation;
  r.segment(offset_[FORCE_RATE], nc) = dd.force_rate;
  // Eq 24: v+ = v + dt q'', q+ = q + dt v+, lambda+ = lambda + dt lambda'.
  auto vn = d->xnext.segment(nv, nv);
  vn = dd.ddq * dt_ + v;
  d->xnext.head(nv) = vn * dt_ + q;
  d->xnext.tail(nc) = dd.force_rate * dt_ + lam;
  weighted_cost(*d, sqrt_w_running_);
  constraint_rows_.calc(d->g, x, u);
}

void IntegratedActionModelSoftContact::calc(const std::shared_ptr<ActionDataAbstract>& data,
                                            const Eigen::Ref<const VectorXd>& x) {
  check_size(x.size(), state_->get_nx(), "x");
  IntegratedActionDataSoftContact* d = static_cast<IntegratedActionDataSoftContact*>(data.get());
  SoftContactDynamicsData& dd = d->dynamics;
  const std::size_t nv = nv_, nc = nc_;
  const auto q = x.head(nv);
  const auto v = x.segment(nv, nv);
  VectorXd& r = d->residual;
  state_residuals(r, x);
  dynamics_.calc_kinematics(dd, q, v);
  r.segment(offset_[TORQUE], nv).setZero();
  r.segment(offset_[FORCE_RATE], nc).setZero();
  d->xnext = x;
  weighted_cost(*d, sqrt_w_state_);
  constraint_rows_.calc(d->g, x);
}

void IntegratedActionModelSoftContact::state_residuals(VectorXd& r,
                                                       const Eigen::Ref<const VectorXd>& x) const {
  const std::size_t nv = nv_, nc = nc_;
  r.segment(offset_[POSTURE], nv) = x.head(nv) - q_reference_;
  r.segment(offset_[JOINT_VELOCITY], nv) = x.segment(nv, nv);
  r.segment(offset_[FORCE], nc) = x.tail(nc) - force_reference_;
  // Joint-limit barrier: the excess x - clip(x, lower, upper) on (q, v), zero inside the bounds.
  const auto xqv = x.head(2 * nv);
  r.segment(offset_[STATE_LIMIT], 2 * nv) =
      xqv - xqv.cwiseMax(state_limit_lower_).cwiseMin(state_limit_upper_);
}

void IntegratedActionModelSoftContact::weighted_cost(IntegratedActionDataSoftContact& d,
                                                     const VectorXd& sqrt_w) const {
  VectorXd& r = d.residual;
  r.segment(offset_[EE_POSITION], 3) = d.dynamics.position - ee_position_reference_;
  r.segment(offset_[EE_VELOCITY], 3) = d.dynamics.ee_velocity;
  d.relative_rotation.noalias() = rotation_reference_.transpose() * d.dynamics.rotation;
  r.segment(offset_[EE_ROTATION], 3) = pinocchio::log3(d.relative_rotation);
  r.segment(offset_[EE_ANGULAR_VELOCITY], 3) = d.dynamics.angular_velocity_local;
  d.r = sqrt_w.cwiseProduct(r);
  d.cost = 0.5 * d.r.squaredNorm();
}

void IntegratedActionModelSoftContact::calcDiff(const std::shared_ptr<ActionDataAbstract>& data,
                                                const Eigen::Ref<const VectorXd>& x,
                                                const Eigen::Ref<const VectorXd>& u) {
  check_size(x.size(), state_->get_nx(), "x");
  if (terminal_) {
    calcDiff(data, x);
    return;
  }
  check_size(u.size(), nu_, "u");
  IntegratedActionDataSoftContact* d = static_cast<IntegratedActionDataSoftContact*>(data.get());
  SoftContactDynamicsData& dd = d->dynamics;
  const std::size_t nv = nv_, nc = nc_;
  const auto q = x.head(nv);
  const auto v = x.segment(nv, nv);
  dynamics_.calc_diff(dd, q, v, u);
  dynamics_.calc_gravity_compensation_diff(dd, q);
  MatrixXd& Rx = d->Rx;
  MatrixXd& Ru = d->Ru;
  Rx.block(offset_[EE_POSITION], 0, 3, nv) = dd.position_dq;
  Rx.block(offset_[EE_VELOCITY], 0, 3, 2 * nv) = dd.ee_velocity_dqv;
  orientation_jacobians(*d);
  Rx.block(offset_[TORQUE], 0, nv, nv) = -dd.gravity_compensation_dq;
  Rx.block(offset_[TORQUE], 2 * nv, nv, nc) = dd.contact_jacobian.transpose();
  state_limit_jacobian(*d, x);
  Rx.middleRows(offset_[FORCE_RATE], nc) = dd.force_rate_dxu.leftCols(ndx_);
  Ru.middleRows(offset_[FORCE_RATE], nc) = dd.force_rate_dxu.rightCols(nv);
  // Costs (Gauss-Newton): Lx = Rx^T W r, Lu = Ru^T W r, Lxx = Rx^T W Rx, Lxu = Rx^T W Ru,
  // Luu = Ru^T W Ru, assembled block by block from the sparsity of Rx, Ru (see
  // add_state_hessian); the same sums as the dense products, a fraction of their cost.
  const VectorXd& w = w_running_;
  d->wr = w.cwiseProduct(d->residual);
  d->Lx.noalias() = Rx.transpose() * d->wr;
  d->Lu.noalias() = Ru.transpose() * d->wr;
  add_state_hessian(*d, w);
  // Torque residual r = u - tau_g(q, lambda): d/dq = -G, d/dlambda = J^T, d/du = I.
  const auto wt = w.segment(offset_[TORQUE], nv);
  const auto G = Rx.block(offset_[TORQUE], 0, nv, nv);  // -d tau_g/dq
  d->WG.noalias() = wt.asDiagonal() * G;
  d->WJt.noalias() = wt.asDiagonal() * dd.contact_jacobian.transpose();
  d->Lxx.topLeftCorner(nv, nv).noalias() += G.transpose().lazyProduct(d->WG);
  d->Lxx.block(0, 2 * nv, nv, nc).noalias() += G.transpose().lazyProduct(d->WJt);
  d->Lxx.block(2 * nv, 2 * nv, nc, nc).noalias() += dd.contact_jacobian.lazyProduct(d->WJt);
  d->Lxx.block(2 * nv, 0, nc, nv) = d->Lxx.block(0, 2 * nv, nv, nc).transpose();
  d->Lxu.setZero();
  d->Lxu.topRows(nv) = d->WG.transpose();
  d->Lxu.bottomRows(nc) = d->WJt.transpose();
  d->Luu.setZero();
  d->Luu.diagonal() = wt;
  // Force-rate residual (nc dense rows): rank-one updates.
  for (std::size_t i = 0; i < nc; ++i) {
    const double wi = w[offset_[FORCE_RATE] + i];
    const auto rx = Rx.row(offset_[FORCE_RATE] + i);
    const auto ru = Ru.row(offset_[FORCE_RATE] + i);
    d->Lxx.noalias() += (wi * rx.transpose()) * rx;
    d->Lxu.noalias() += (wi * rx.transpose()) * ru;
    d->Luu.noalias() += (wi * ru.transpose()) * ru;
  }
  // Dynamics (eq 24): [Fx Fu] = [I 0] + [dt^2; dt; dt] d f/d(x, u), plus dt on dq+/dv.
  MatrixXd& Fxu = d->Fxu;
  Fxu.setZero();
  Fxu.leftCols(ndx_).setIdentity();
  Fxu.block(0, nv, nv, nv).diagonal().array() += dt_;
  Fxu.topRows(nv) += (dt_ * dt_) * dd.ddq_dxu;
  Fxu.middleRows(nv, nv) += dt_ * dd.ddq_dxu;
  Fxu.bottomRows(nc) += dt_ * dd.force_rate_dxu;
  d->Fx = Fxu.leftCols(ndx_);
  d->Fu = Fxu.rightCols(nv);
  constraint_rows_.calcDiff(d->Gx, d->Gu);
}

void IntegratedActionModelSoftContact::calcDiff(const std::shared_ptr<ActionDataAbstract>& data,
                                                const Eigen::Ref<const VectorXd>& x) {
  check_size(x.size(), state_->get_nx(), "x");
  IntegratedActionDataSoftContact* d = static_cast<IntegratedActionDataSoftContact*>(data.get());
  SoftContactDynamicsData& dd = d->dynamics;
  const std::size_t nv = nv_;
  dynamics_.calc_kinematics_diff(dd, x.head(nv), x.segment(nv, nv));
  MatrixXd& Rx = d->Rx;
  Rx.block(offset_[EE_POSITION], 0, 3, nv) = dd.position_dq;
  Rx.block(offset_[EE_VELOCITY], 0, 3, 2 * nv) = dd.ee_velocity_dqv;
  orientation_jacobians(*d);
  state_limit_jacobian(*d, x);
  const VectorXd& w = w_state_;  // torque and force-rate weights are zero
  d->wr = w.cwiseProduct(d->residual);
  d->Lx.noalias() = Rx.transpose() * d->wr;
  add_state_hessian(*d, w);
  d->Fx.setIdentity();
  d->Fu.setZero();
  d->Lu.setZero();
  d->Luu.setZero();
  d->Lxu.setZero();
  constraint_rows_.calcDiff(d->Gx, d->Gu);
}

std::shared_ptr<crocoddyl::ActionDataAbstractTpl<double>>
IntegratedActionModelSoftContact::createData() {
  return std::allocate_shared<IntegratedActionDataSoftContact>(
      Eigen::aligned_allocator<IntegratedActionDataSoftContact>(), this);
}

bool IntegratedActionModelSoftContact::checkData(
    const std::shared_ptr<ActionDataAbstract>& data) {
  return std::dynamic_pointer_cast<IntegratedActionDataSoftContact>(data) != nullptr;
}

std::shared_ptr<crocoddyl::ActionModelBase> IntegratedActionModelSoftContact::cloneAsDouble()
    const {
  return std::allocate_shared<IntegratedActionModelSoftContact>(
      Eigen::aligned_allocator<IntegratedActionModelSoftContact>(), *this);
}

std::shared_ptr<crocoddyl::ActionModelBase> IntegratedActionModelSoftContact::cloneAsFloat()
    const {
  throw ConfigError("IntegratedActionModelSoftContact exists in double precision only");
}

void IntegratedActionModelSoftContact::print(std::ostream& os) const {
  os << "IntegratedActionModelSoftContact {nv=" << nv_ << ", nc=" << nc_ << ", dt=" << dt_
     << ", terminal=" << (terminal_ ? "true" : "false")
     << ", frame=" << (dynamics_.world_aligned() ? "LOCAL_WORLD_ALIGNED" : "LOCAL") << "}";
}

IntegratedActionDataSoftContact::IntegratedActionDataSoftContact(
    IntegratedActionModelSoftContact* const model)
    : Base(static_cast<crocoddyl::ActionModelAbstractTpl<double>*>(model)),
      dynamics(model->dynamics().pin_model(), model->get_nc()),
      residual(VectorXd::Zero(model->get_nr())),
      wr(VectorXd::Zero(model->get_nr())),
      Rx(MatrixXd::Zero(model->get_nr(), model->get_ndx())),
      Ru(MatrixXd::Zero(model->get_nr(), model->get_nv())),
      WG(MatrixXd::Zero(model->get_nv(), model->get_nv())),
      WJt(MatrixXd::Zero(model->get_nv(), model->get_nc())),
      Fxu(MatrixXd::Zero(model->get_ndx(), model->get_ndx() + model->get_nv())),
      relative_rotation(Eigen::Matrix3d::Identity()),
      jlog(Eigen::Matrix3d::Identity()) {
  const std::size_t nv = model->get_nv(), nc = model->get_nc();
  // Constant blocks of the residual Jacobians.
  Rx.block(model->term_offset(POSTURE), 0, nv, nv).setIdentity();
  Rx.block(model->term_offset(JOINT_VELOCITY), nv, nv, nv).setIdentity();
  Rx.block(model->term_offset(FORCE), 2 * nv, nc, nc).setIdentity();
  Ru.block(model->term_offset(TORQUE), 0, nv, nv).setIdentity();
}

// ======================================================================= bindings
namespace bp = boost::python;

namespace {

typedef IntegratedActionModelSoftContact Model;
typedef IntegratedActionDataSoftContact Data;
typedef crocoddyl::ActionDataAbstractTpl<double> ActionData;

// Eigen members as numpy arrays sharing the C++ memory (like crocoddyl's data.Fx).
#define FFMPC_MEMBER(cls, name) bp::make_getter(&cls::name, bp::return_internal_reference<>())

VectorXd copy_vector(const VectorXd& v) { return v; }

}  // namespace

void expose_soft_contact() {
  bp::register_ptr_to_python<std::shared_ptr<Model>>();
  bp::register_ptr_to_python<std::shared_ptr<Data>>();

  bp::class_<SoftContactDynamicsData, boost::noncopyable>(
      "SoftContactDynamicsData",
      "Workspace of the force-feedback dynamics (fields as in "
      "ffmpc_core.soft_contact.SoftContactDynamicsData).",
      bp::no_init)
      .add_property("force_local", FFMPC_MEMBER(SoftContactDynamicsData, force_local))
      .add_property("rotation", FFMPC_MEMBER(SoftContactDynamicsData, rotation))
      .add_property("position", FFMPC_MEMBER(SoftContactDynamicsData, position))
      .add_property("ee_velocity", FFMPC_MEMBER(SoftContactDynamicsData, ee_velocity))
      .add_property("frame_velocity", FFMPC_MEMBER(SoftContactDynamicsData, frame_velocity))
      .add_property("frame_acceleration",
                    FFMPC_MEMBER(SoftContactDynamicsData, frame_acceleration))
      .add_property("ddq", FFMPC_MEMBER(SoftContactDynamicsData, ddq))
      .add_property("force_rate", FFMPC_MEMBER(SoftContactDynamicsData, force_rate))
      .add_property("gravity_compensation",
                    FFMPC_MEMBER(SoftContactDynamicsData, gravity_compensation))
      .add_property("ddq_dxu", FFMPC_MEMBER(SoftContactDynamicsData, ddq_dxu))
      .add_property("force_rate_dxu", FFMPC_MEMBER(SoftContactDynamicsData, force_rate_dxu))
      .add_property("contact_jacobian", FFMPC_MEMBER(SoftContactDynamicsData, contact_jacobian))
      .add_property("position_dq", FFMPC_MEMBER(SoftContactDynamicsData, position_dq))
      .add_property("ee_velocity_dqv", FFMPC_MEMBER(SoftContactDynamicsData, ee_velocity_dqv))
      .add_property("gravity_compensation_dq",
                    FFMPC_MEMBER(SoftContactDynamicsData, gravity_compensation_dq))
      .add_property("gravity_compensation_dforce",
                    FFMPC_MEMBER(SoftContactDynamicsData, gravity_compensation_dforce));

  bp::class_<Model, bp::bases<crocoddyl::ActionModelAbstract>>(
      "IntegratedActionModelSoftContact",
      "Force-feedback OCP node (eq 24 + costs eq 25, 29) in C++: see "
      "ffmpc_core.native.IntegratedActionModelSoftContactNative for the Python interface.",
      bp::init<const pinocchio::Model&, std::size_t, std::size_t, bool, std::size_t, double,
               bool, Eigen::MatrixXd, Eigen::VectorXd>(
          bp::args("self", "pin_model", "frame_id", "dimension", "world_aligned", "normal_axis",
                   "dt", "terminal", "constraint_matrix", "control_scale"),
          "Build a node; weights, activations, references and K, B start at zero (set them "
          "with the setters). constraint_matrix: the state-only constraint rows S (0 rows: "
          "none); a running node adds the control rows control_scale .* u; bounds in g_lb, "
          "g_ub."))
      .def<void (Model::*)(const std::shared_ptr<ActionData>&, const Eigen::Ref<const VectorXd>&,
                           const Eigen::Ref<const VectorXd>&)>(
          "calc", &Model::calc, bp::args("self", "data", "x", "u"),
          "Next state (eq 24) and cost at x = [q, v, lambda], u = tau.")
      .def<void (Model::*)(const std::shared_ptr<ActionData>&,
                           const Eigen::Ref<const VectorXd>&)>(
          "calc", &Model::calc, bp::args("self", "data", "x"), "State terms only (x+ = x).")
      .def<void (Model::*)(const std::shared_ptr<ActionData>&, const Eigen::Ref<const VectorXd>&,
                           const Eigen::Ref<const VectorXd>&)>(
          "calcDiff", &Model::calcDiff, bp::args("self", "data", "x", "u"),
          "Fx, Fu and the Gauss-Newton cost derivatives (call calc first).")
      .def<void (Model::*)(const std::shared_ptr<ActionData>&,
                           const Eigen::Ref<const VectorXd>&)>(
          "calcDiff", &Model::calcDiff, bp::args("self", "data", "x"))
      .def("createData", &Model::createData, bp::args("self"), "A fresh workspace.")
      .def("checkData", &Model::checkData, bp::args("self", "data"))
      .def("set_weight", &Model::set_weight, bp::args("self", "name", "value"),
           "Scalar weight c of a cost term (ConfigError on a bad name or value).")
      .def("weight", &Model::weight, bp::args("self", "name"),
           "Scalar weight c of a cost term, as set (before the in-contact rule).")
      .def("set_activation", &Model::set_activation, bp::args("self", "name", "diag"),
           "Activation diagonal Q of a cost term (1 entry broadcasts).")
      .def("activation", &Model::activation, bp::return_value_policy<bp::copy_const_reference>(),
           bp::args("self", "name"))
      .def("_set_reference_values", &Model::set_reference_values,
           bp::args("self", "ee_position", "force", "ee_position_weight", "force_weight",
                    "in_contact", "posture", "ee_position_diag"),
           "All arrays as float64; empty posture / ee_position_diag mean None.")
      .def("set_in_contact", &Model::set_in_contact, bp::args("self", "in_contact"),
           "In contact: K, B nominal; otherwise K = B = 0 and c6 = 0 for this node.")
      .def("_set_contact_parameters", &Model::set_contact_parameters,
           bp::args("self", "stiffness", "damping"))
      .def("_set_q_reference", &Model::set_q_reference, bp::args("self", "q_reference"))
      .def("_set_rotation_reference", &Model::set_rotation_reference,
           bp::args("self", "rotation"),
           "R_bar of the orientation cost (3x3 rotation matrix, ConfigError otherwise).")
      .def("_set_state_limit_bounds", &Model::set_state_limit_bounds,
           bp::args("self", "lower", "upper"),
           "Joint-limit barrier bounds on (q, v), 2 nv entries each (rad, rad/s).")
      .add_property("state_limit_lower",
                    +[](const Model& m) { return copy_vector(m.get_state_limit_lower()); },
                    "Lower bounds of the joint-limit barrier on (q, v), rad and rad/s (copy).")
      .add_property("state_limit_upper",
                    +[](const Model& m) { return copy_vector(m.get_state_limit_upper()); },
                    "Upper bounds of the joint-limit barrier on (q, v), rad and rad/s (copy).")
      .add_property("constraint_matrix",
                    +[](const Model& m) { return Eigen::MatrixXd(m.get_constraint_matrix()); },
                    "The state-only constraint rows S (a copy).")
      // crocoddyl 3.2.1 binds ng / ng_T on its Python wrapper class only: a C++ subclass's
      // Python object cannot read them there.
      .add_property("ng", +[](const Model& m) { return m.get_ng(); },
                    "Constraint rows of a node with a control (a running node).")
      .add_property("ng_T", +[](const Model& m) { return m.get_ng_T(); },
                    "Constraint rows of a call without a control (a terminal node).")
      .add_property("dt", &Model::get_dt, "Node duration, s.")
      .add_property("terminal", &Model::get_terminal)
      .add_property("in_contact", &Model::get_in_contact)
      .add_property("nv", &Model::get_nv)
      .add_property("nc", &Model::get_nc)
      .add_property("ndx", &Model::get_ndx)
      .add_property("world_aligned",
                    +[](const Model& m) { return m.dynamics().world_aligned(); })
      .add_property("frame_id", +[](const Model& m) { return m.dynamics().frame_id(); })
      .add_property("normal_axis", +[](const Model& m) { return m.dynamics().normal_axis(); })
      .add_property("stiffness",
                    +[](const Model& m) { return copy_vector(m.dynamics().stiffness()); },
                    "K in use (N/m): nominal in contact, 0 out of contact (copy).")
      .add_property("damping", +[](const Model& m) { return copy_vector(m.dynamics().damping()); },
                    "B in use (N s/m) (copy).")
      .add_property("nominal_stiffness",
                    +[](const Model& m) { return copy_vector(m.get_nominal_stiffness()); })
      .add_property("nominal_damping",
                    +[](const Model& m) { return copy_vector(m.get_nominal_damping()); })
      .add_property("q_reference",
                    +[](const Model& m) { return copy_vector(m.get_q_reference()); },
                    "q_bar, rad (copy).")
      .add_property("ee_position_reference",
                    +[](const Model& m) { return copy_vector(m.get_ee_position_reference()); },
                    "p_bar, m, world (copy).")
      .add_property("rotation_reference",
                    +[](const Model& m) { return Eigen::Matrix3d(m.get_rotation_reference()); },
                    "R_bar of the orientation cost (copy).")
      .add_property("force_reference",
                    +[](const Model& m) { return copy_vector(m.get_force_reference()); },
                    "lambda_bar, N (copy).")
      .add_property("weights_running",
                    +[](const Model& m) { return copy_vector(m.get_weights_running()); },
                    "w of cost = 1/2 sum w r^2 for a running node (copy).")
      .add_property("weights_state",
                    +[](const Model& m) { return copy_vector(m.get_weights_state()); },
                    "w for a terminal node / a call without u (copy).")
      .def(bp::self_ns::str(bp::self_ns::self));

  bp::class_<Data, bp::bases<crocoddyl::ActionDataAbstract>>(
      "IntegratedActionDataSoftContact", "Workspace of IntegratedActionModelSoftContact.",
      bp::init<Model*>(bp::args("self", "model"))[bp::with_custodian_and_ward<1, 2>()])
      .add_property("dynamics", bp::make_getter(&Data::dynamics, bp::return_internal_reference<>()))
      .add_property("residual", FFMPC_MEMBER(Data, residual), "Unweighted stacked residual r.")
      .add_property("Rx", FFMPC_MEMBER(Data, Rx))
      .add_property("Ru", FFMPC_MEMBER(Data, Ru));
}

#undef FFMPC_MEMBER

}  // namespace ffmpc
