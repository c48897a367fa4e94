// Force-feedback OCP node (paper section V, eq 16-24; costs eq 25, 29): the C++ port of
// ffmpc_core/soft_contact.py (SoftContactDynamics, IntegratedActionModelSoftContact), which stays
// the readable reference; tests/test_native_soft_contact.py holds the two equal.
//
// State x = (q, v, lambda) (rad, rad/s, N) on a crocoddyl::StateVector(2 nv + nc), control
// u = tau (N m). lambda is the force the environment exerts on the robot at the origin of the
// robot's contact frame, in LOCAL_WORLD_ALIGNED (world axes, force fixed in the world) or LOCAL
// (contact axes) components; nc = 1 (component along normal_axis) or 3.
#pragma once

#include <array>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <crocoddyl/core/action-base.hpp>
#include <crocoddyl/core/states/euclidean.hpp>
#include <pinocchio/multibody/data.hpp>
#include <pinocchio/multibody/model.hpp>

#include "constraint_rows.hpp"

namespace ffmpc {

typedef Eigen::VectorXd VectorXd;
typedef Eigen::MatrixXd MatrixXd;
typedef Eigen::Matrix<double, 6, Eigen::Dynamic> Matrix6xd;
typedef Eigen::Matrix<double, 3, Eigen::Dynamic> Matrix3xd;

/// Preallocated workspace of SoftContactDynamics (one per OCP node). Field meanings, units and
/// frames are those of ffmpc_core.soft_contact.SoftContactDynamicsData.
struct SoftContactDynamicsData {
  EIGEN_MAKE_ALIGNED_OPERATOR_NEW

  SoftContactDynamicsData(const pinocchio::Model& model, std::size_t nc);

  pinocchio::Data pinocchio;         // kinematics (LOCAL): frame placement, velocity, acceleration
  pinocchio::Data pinocchio_aba;     // ABA in WORLD convention, reused by its derivatives
  pinocchio::Data pinocchio_static;  // tau_g(q, lambda) (v = a = 0)
  std::vector<pinocchio::Force> fext;
  // calc
  Eigen::Vector3d force_frame, force_local;
  Eigen::Matrix3d rotation;  // R = oR_contact
  Eigen::Vector3d position;  // p, m, world
  Eigen::Vector3d linear_velocity_local, angular_velocity_local, classical_acceleration_local;
  Eigen::Vector3d ee_velocity;                          // m/s, world axes
  Eigen::Vector3d frame_velocity, frame_acceleration;  // in the force frame's axes
  VectorXd ddq;                   // rad/s^2
  VectorXd force_rate;            // N/s
  VectorXd gravity_compensation;  // N m
  // calc_diff: Jacobians w.r.t. (q, v, lambda, tau) stacked column-wise
  MatrixXd ddq_dxu;         // nv x (2nv + nc + nv)
  MatrixXd force_rate_dxu;  // nc x ...
  Matrix3xd frame_velocity_dxu, frame_acceleration_dxu, local_acceleration_dxu;
  Matrix6xd velocity_dq;  // d(LOCAL twist)/dq
  Matrix6xd jacobian;     // 6 x nv LOCAL Jacobian of the contact frame
  Matrix6xd acceleration_dq, acceleration_dv;
  MatrixXd minv;              // M^-1 (symmetric)
  MatrixXd contact_jacobian;  // nc x nv (rows matching lambda, m/rad)
  Matrix3xd position_dq;      // dp/dq, world
  Matrix3xd ee_velocity_dqv;  // [d pdot_world/dq, d pdot_world/dv]
  MatrixXd gravity_compensation_dq, gravity_compensation_dforce;
  // scratch
  Eigen::Matrix<double, Eigen::Dynamic, 3> minv_jlin_t;
  Matrix3xd tmp_3nv;
  Matrix3xd local_velocity_dqv;
  Matrix3xd tmp_3x2nv;
  VectorXd zero_nv;
};

/// The force-feedback contact dynamics (eq 20) and derivatives (eq 22, 23a-d).
class SoftContactDynamics {
 public:
  EIGEN_MAKE_ALIGNED_OPERATOR_NEW

  SoftContactDynamics(const pinocchio::Model& model, std::size_t frame_id, std::size_t nc,
                      bool world_aligned, std::size_t normal_axis);

  /// K (N/m) and B (N s/m): nc entries (or 1, broadcast), finite, >= 0 (ConfigError otherwise).
  void set_contact_parameters(const VectorXd& stiffness, const VectorXd& damping);

  void calc(SoftContactDynamicsData& d, const Eigen::Ref<const VectorXd>& q,
            const Eigen::Ref<const VectorXd>& v, const Eigen::Ref<const VectorXd>& force,
            const Eigen::Ref<const VectorXd>& tau) const;
  void calc_kinematics(SoftContactDynamicsData& d, const Eigen::Ref<const VectorXd>& q,
                       const Eigen::Ref<const VectorXd>& v) const;
  void calc_gravity_compensation(SoftContactDynamicsData& d,
                                 const Eigen::Ref<const VectorXd>& q) const;
  /// Needs calc at the same (q, v, lambda, tau) first: its WORLD-convention ABA pass is reused
  /// (tau is therefore not read again).
  void calc_diff(SoftContactDynamicsData& d, const Eigen::Ref<const VectorXd>& q,
                 const Eigen::Ref<const VectorXd>& v, const Eigen::Ref<const VectorXd>& tau) const;
  void calc_kinematics_diff(SoftContactDynamicsData& d, const Eigen::Ref<const VectorXd>& q,
                            const Eigen::Ref<const VectorXd>& v) const;
  void calc_gravity_compensation_diff(SoftContactDynamicsData& d,
                                      const Eigen::Ref<const VectorXd>& q) const;

  const pinocchio::Model& pin_model() const { return model_; }
  std::size_t nv() const { return nv_; }
  std::size_t nc() const { return nc_; }
  std::size_t frame_id() const { return frame_id_; }
  std::size_t normal_axis() const { return normal_axis_; }
  bool world_aligned() const { return world_aligned_; }
  const VectorXd& stiffness() const { return stiffness_; }
  const VectorXd& damping() const { return damping_; }

 private:
  void set_external_force(SoftContactDynamicsData& d, const Eigen::Ref<const VectorXd>& force) const;
  void read_frame_kinematics(SoftContactDynamicsData& d) const;
  std::size_t row(std::size_t i) const { return nc_ == 1 ? normal_axis_ : i; }

  pinocchio::Model model_;
  std::size_t nv_, nc_, frame_id_, parent_joint_, normal_axis_;
  bool world_aligned_;
  Eigen::Matrix<double, 6, 3> force_to_joint_;  // [jRf; [jpf]x jRf]
  VectorXd stiffness_, damping_;
};

/// Residual blocks, in the order of ffmpc_core.soft_contact.RESIDUAL_TERMS. STATE_LIMIT: the
/// joint-limit barrier on (q, v), 2 nv rows, the excess x - clip(x, lower, upper) (rad, rad/s).
/// EE_ROTATION: log3(R_bar^T R(q)), 3 rows (rad; crocoddyl's ResidualModelFrameRotation).
/// EE_ANGULAR_VELOCITY: the contact frame's LOCAL angular velocity, 3 rows (rad/s; the angular
/// rows of crocoddyl's ResidualModelFrameVelocity in LOCAL).
enum Term {
  POSTURE = 0,
  JOINT_VELOCITY,
  TORQUE,
  EE_POSITION,
  EE_VELOCITY,
  FORCE,
  FORCE_RATE,
  STATE_LIMIT,
  EE_ROTATION,
  EE_ANGULAR_VELOCITY
};
constexpr std::size_t kNumTerms = 10;

struct IntegratedActionDataSoftContact;

/// One node of the force-feedback OCP: eq 24 (semi-implicit Euler) + costs eq 25 and 29, with the
/// Gauss-Newton Hessians. See ffmpc_core.soft_contact.IntegratedActionModelSoftContact.
class IntegratedActionModelSoftContact : public crocoddyl::ActionModelAbstractTpl<double> {
 public:
  EIGEN_MAKE_ALIGNED_OPERATOR_NEW
  typedef crocoddyl::ActionModelAbstractTpl<double> Base;
  typedef crocoddyl::ActionDataAbstractTpl<double> ActionDataAbstract;

  /// `constraint_matrix`: the state-only constraint rows S (n_s x nx, 0 rows: unconstrained);
  /// a running node also has the control rows control_scale .* u (constraint_rows.hpp).
  /// Bounds: g_lb, g_ub.
  IntegratedActionModelSoftContact(const pinocchio::Model& model, std::size_t frame_id,
                                   std::size_t nc, bool world_aligned, std::size_t normal_axis,
                                   double dt, bool terminal,
                                   const Eigen::MatrixXd& constraint_matrix,
                                   const Eigen::VectorXd& control_scale);
  virtual ~IntegratedActionModelSoftContact() = default;

  virtual void calc(const std::shared_ptr<ActionDataAbstract>& data,
                    const Eigen::Ref<const VectorXd>& x, const Eigen::Ref<const VectorXd>& u);
  virtual void calc(const std::shared_ptr<ActionDataAbstract>& data,
                    const Eigen::Ref<const VectorXd>& x);
  virtual void calcDiff(const std::shared_ptr<ActionDataAbstract>& data,
                        const Eigen::Ref<const VectorXd>& x, const Eigen::Ref<const VectorXd>& u);
  virtual void calcDiff(const std::shared_ptr<ActionDataAbstract>& data,
                        const Eigen::Ref<const VectorXd>& x);
  virtual std::shared_ptr<ActionDataAbstract> createData();
  virtual bool checkData(const std::shared_ptr<ActionDataAbstract>& data);
  virtual std::shared_ptr<crocoddyl::ActionModelBase> cloneAsDouble() const;
  virtual std::shared_ptr<crocoddyl::ActionModelBase> cloneAsFloat() const;
  virtual void print(std::ostream& os) const;

  // ------------------------------------------------------------ parameters (validated)
  /// Scalar weight c of a term (ConfigError: unknown name, negative or non-finite).
  void set_weight(const std::string& name, double value);
  double weight(const std::string& name) const;
  /// Activation diagonal Q of a term (configuration); for ee_position it is also the default
  /// that set_reference_values restores when given no ee_position_diag.
  void set_activation(const std::string& name, const VectorXd& diag);
  const VectorXd& activation(const std::string& name) const;
  /// p_bar (m, world, 3), lambda_bar (N, nc), c4, c6, contact flag, q_bar (rad, nv; empty keeps
  /// it) and Q4 (3, world axes; empty restores the default). InputError leaves all unchanged.
  void set_reference_values(const VectorXd& ee_position, const VectorXd& force,
                            double ee_position_weight, double force_weight, bool in_contact,
                            const VectorXd& posture, const VectorXd& ee_position_diag);
  void set_in_contact(bool in_contact);
  /// Nominal K (N/m), B (N s/m): nc entries or 1 (broadcast), finite, >= 0 (ConfigError).
  void set_contact_parameters(const VectorXd& stiffness, const VectorXd& damping);
  /// q_bar (rad, nv entries; ConfigError on a bad value): configuration-time posture reference.
  void set_q_reference(const VectorXd& q_reference);
  /// R_bar of the orientation cost (3x3, finite, orthonormal with det +1 to 1e-9: ConfigError
  /// otherwise). Default identity; the Python wrapper sets the contact frame's orientation at q_bar.
  void set_rotation_reference(const Eigen::Matrix3d& rotation);
  /// Bounds of the joint-limit barrier on (q, v): 2 nv entries each (rad, then rad/s),
  /// lower <= upper, no NaN (+-inf: no bound); ConfigError leaves them unchanged. Default +-inf.
  void set_state_limit_bounds(const VectorXd& lower, const VectorXd& upper);

  const SoftContactDynamics& dynamics() const { return dynamics_; }
  double get_dt() const { return dt_; }
  bool get_terminal() const { return terminal_; }
  bool get_in_contact() const { return in_contact_; }
  std::size_t get_nv() const { return nv_; }
  std::size_t get_nc() const { return nc_; }
  std::size_t get_ndx() const { return ndx_; }
  std::size_t term_offset(std::size_t k) const { return offset_[k]; }
  std::size_t term_size(std::size_t k) const { return size_[k]; }
  const VectorXd& get_q_reference() const { return q_reference_; }
  const VectorXd& get_ee_position_reference() const { return ee_position_reference_; }
  const VectorXd& get_force_reference() const { return force_reference_; }
  const Eigen::Matrix3d& get_rotation_reference() const { return rotation_reference_; }
  const VectorXd& get_nominal_stiffness() const { return nominal_stiffness_; }
  const VectorXd& get_nominal_damping() const { return nominal_damping_; }
  const VectorXd& get_weights_running() const { return w_running_; }
  const VectorXd& get_weights_state() const { return w_state_; }
  const VectorXd& get_state_limit_lower() const { return state_limit_lower_; }
  const VectorXd& get_state_limit_upper() const { return state_limit_upper_; }
  const Eigen::MatrixXd& get_constraint_matrix() const { return constraint_rows_.state_matrix; }

 private:
  void update_weights();
  /// Posture, joint-velocity and force residuals of x (rows of every node, running or not).
  void state_residuals(VectorXd& r, const Eigen::Ref<const VectorXd>& x) const;
  /// End-effector residuals from data.dynamics' kinematics, then r = √w ∘ residual and
  /// cost = ½‖r‖².
  void weighted_cost(IntegratedActionDataSoftContact& d, const VectorXd& sqrt_w) const;
  /// The joint-limit barrier's Jacobian block of data.Rx: 1 on the diagonal where x is at or
  /// beyond a bound (crocoddyl's ActivationModelQuadraticBarrier rule), 0 elsewhere.
  void state_limit_jacobian(IntegratedActionDataSoftContact& d,
                            const Eigen::Ref<const VectorXd>& x) const;
  /// Rows of data.Rx of the orientation and angular-velocity residuals (after a kinematics
  /// derivative pass of data.dynamics).
  void orientation_jacobians(IntegratedActionDataSoftContact& d) const;
  /// Gauss-Newton Lxx of the state terms (weights w), from the sparsity of data.Rx.
  void add_state_hessian(IntegratedActionDataSoftContact& d, const VectorXd& w) const;

  SoftContactDynamics dynamics_;
  std::size_t nv_, nc_, ndx_;
  double dt_;
  bool terminal_;
  bool in_contact_;
  std::array<std::size_t, kNumTerms> offset_, size_;
  std::array<double, kNumTerms> c_;
  std::array<VectorXd, kNumTerms> diag_;
  VectorXd default_ee_position_diag_;
  VectorXd q_reference_, ee_position_reference_, force_reference_;
  Eigen::Matrix3d rotation_reference_;  // R_bar of the orientation cost
  VectorXd nominal_stiffness_, nominal_damping_;
  VectorXd state_limit_lower_, state_limit_upper_;  // 2 nv: rad, then rad/s
  VectorXd w_running_, w_state_, sqrt_w_running_, sqrt_w_state_;
  ConstraintRows constraint_rows_;
};

/// Workspace of IntegratedActionModelSoftContact.
struct IntegratedActionDataSoftContact : public crocoddyl::ActionDataAbstractTpl<double> {
  EIGEN_MAKE_ALIGNED_OPERATOR_NEW
  typedef crocoddyl::ActionDataAbstractTpl<double> Base;

  explicit IntegratedActionDataSoftContact(IntegratedActionModelSoftContact* const model);
  virtual ~IntegratedActionDataSoftContact() = default;

  SoftContactDynamicsData dynamics;
  VectorXd residual;  // unweighted stacked residual (RESIDUAL_TERMS layout)
  VectorXd wr;        // W r
  MatrixXd Rx, Ru;    // residual Jacobians
  MatrixXd WG;        // W_tau (d r_tau/dq), nv x nv
  MatrixXd WJt;       // W_tau J^T, nv x nc
  MatrixXd Fxu;       // [Fx Fu]
  Eigen::Matrix3d relative_rotation;  // R_bar^T R(q)
  Eigen::Matrix3d jlog;               // Jlog3(R_bar^T R(q))
};

void expose_soft_contact();

}  // namespace ffmpc
