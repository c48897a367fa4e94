// Custom crocoddyl residuals of the classical and torque-feedback formulations (paper eq 25.3,
// 25.5): C++ ports of ffmpc_core/rigid_contact.py's ResidualModelContactGravityTorque and
// ResidualModelFrameLinearVelocityWorld, with the same residuals and exact derivatives; and the
// classical formulation's hard-constraint rows (ResidualModelConstraintRows, issue 23).
#ifndef FFMPC_CPP_RESIDUALS_HPP_
#define FFMPC_CPP_RESIDUALS_HPP_

#include <memory>
#include <stdexcept>
#include <string>

#include <crocoddyl/core/residual-base.hpp>
#include <crocoddyl/multibody/contact-base.hpp>
#include <crocoddyl/multibody/contacts/multiple-contacts.hpp>
#include <crocoddyl/multibody/data/contacts.hpp>
#include <crocoddyl/multibody/data/multibody.hpp>
#include <crocoddyl/multibody/states/multibody.hpp>
#include <pinocchio/multibody/data.hpp>
#include <pinocchio/multibody/model.hpp>

#include "constraint_rows.hpp"
#include "errors.hpp"

namespace ffmpc {


typedef crocoddyl::MathBaseTpl<double>::VectorXs VectorXd;
typedef crocoddyl::MathBaseTpl<double>::MatrixXs MatrixXd;

/// Eq 25.3 in contact: r = τ − τ_g(q, λ^r(x, u)), τ_g(q, λ) = g(q) − J(q)ᵀλ, N·m.
///
/// λ^r is the rigid contact force of the same node, read from the contact data of the
/// differential model (DifferentialActionModelContactFwdDynamics with enable_force) after its
/// calc. Derivatives: ∂r/∂q = −∂τ_g/∂q|_λ + Jᵀ·∂λ/∂q, ∂r/∂v = Jᵀ·∂λ/∂v, ∂r/∂u = I + Jᵀ·∂λ/∂u,
/// the force held fixed in its own frame (world axes for LOCAL_WORLD_ALIGNED: crocoddyl's
/// contact dtau_dq correction). calc(x) (no control, no force) gives r = −g(q).
class ResidualModelContactGravityTorque : public crocoddyl::ResidualModelAbstract {
 public:
  EIGEN_MAKE_ALIGNED_OPERATOR_NEW
  typedef crocoddyl::ResidualModelAbstract Base;
  typedef crocoddyl::ResidualDataAbstract ResidualDataAbstract;
  typedef crocoddyl::DataCollectorAbstract DataCollectorAbstract;
  typedef crocoddyl::StateMultibody StateMultibody;

  /// `contact_name`: the contact (in the differential model's ContactModelMultiple) whose force
  /// λ^r enters τ_g; `world_aligned`: its frame type is LOCAL_WORLD_ALIGNED.
  ResidualModelContactGravityTorque(std::shared_ptr<StateMultibody> state, std::size_t nu,
                                    bool world_aligned, const std::string& contact_name);
  virtual ~ResidualModelContactGravityTorque() = default;

  void calc(const std::shared_ptr<ResidualDataAbstract>& data,
            const Eigen::Ref<const VectorXd>& x, const Eigen::Ref<const VectorXd>& u) override;
  void calc(const std::shared_ptr<ResidualDataAbstract>& data,
            const Eigen::Ref<const VectorXd>& x) override;
  void calcDiff(const std::shared_ptr<ResidualDataAbstract>& data,
                const Eigen::Ref<const VectorXd>& x,
                const Eigen::Ref<const VectorXd>& u) override;
  void calcDiff(const std::shared_ptr<ResidualDataAbstract>& data,
                const Eigen::Ref<const VectorXd>& x) override;
  std::shared_ptr<ResidualDataAbstract> createData(DataCollectorAbstract* const data) override;
  std::shared_ptr<crocoddyl::ResidualModelBase> cloneAsDouble() const override;
  std::shared_ptr<crocoddyl::ResidualModelBase> cloneAsFloat() const override;
  void print(std::ostream& os) const override;

  bool get_world_aligned() const { return world_aligned_; }
  const std::string& get_contact_name() const { return contact_name_; }
  const pinocchio::Model& get_pinocchio() const { return *pin_model_; }

 private:
  std::shared_ptr<pinocchio::Model> pin_model_;
  bool world_aligned_;
  std::string contact_name_;
};

/// Workspace of ResidualModelContactGravityTorque: the live contact data of the differential
/// model (fext, Jc, df_dx, df_du, dtau_dq) and a private pinocchio data.
struct ResidualDataContactGravityTorque : public crocoddyl::ResidualDataAbstract {
  EIGEN_MAKE_ALIGNED_OPERATOR_NEW
  typedef crocoddyl::ResidualDataAbstract Base;

  ResidualDataContactGravityTorque(ResidualModelContactGravityTorque* const model,
                                   crocoddyl::DataCollectorAbstract* const data);
  virtual ~ResidualDataContactGravityTorque() = default;

  pinocchio::Data pinocchio;                                ///< private pinocchio data
  std::shared_ptr<crocoddyl::ContactDataMultiple> contacts;  ///< the DAM's contact data
  std::shared_ptr<crocoddyl::ContactDataAbstract> contact;   ///< the named contact's data
  MatrixXd dtau_g_dq;  ///< ∂τ_g/∂q with the force fixed (nv × nv), N·m/rad
  std::size_t nc;      ///< contact dimension (1 or 3)
};

/// Eq 25.5: ṗ(q, q̇), linear velocity of the frame origin in world axes (pinocchio
/// LOCAL_WORLD_ALIGNED), m/s. With ṗ = R·v_l (R world rotation of the frame, v_l its LOCAL linear
/// velocity): ∂ṗ/∂q = R·(∂v_l/∂q − [v_l]×·J_ω), ∂ṗ/∂v = R·J_v (LOCAL Jacobian blocks J_v, J_ω).
class ResidualModelFrameLinearVelocityWorld : public crocoddyl::ResidualModelAbstract {
 public:
  EIGEN_MAKE_ALIGNED_OPERATOR_NEW
  typedef crocoddyl::ResidualModelAbstract Base;
  typedef crocoddyl::ResidualDataAbstract ResidualDataAbstract;
  typedef crocoddyl::DataCollectorAbstract DataCollectorAbstract;
  typedef crocoddyl::StateMultibody StateMultibody;

  ResidualModelFrameLinearVelocityWorld(std::shared_ptr<StateMultibody> state,
                                        pinocchio::FrameIndex frame_id, std::size_t nu);
  virtual ~ResidualModelFrameLinearVelocityWorld() = default;

  void calc(const std::shared_ptr<ResidualDataAbstract>& data,
            const Eigen::Ref<const VectorXd>& x, const Eigen::Ref<const VectorXd>& u) override;
  void calc(const std::shared_ptr<ResidualDataAbstract>& data,
            const Eigen::Ref<const VectorXd>& x) override;
  void calcDiff(const std::shared_ptr<ResidualDataAbstract>& data,
                const Eigen::Ref<const VectorXd>& x,
                const Eigen::Ref<const VectorXd>& u) override;
  void calcDiff(const std::shared_ptr<ResidualDataAbstract>& data,
                const Eigen::Ref<const VectorXd>& x) override;
  std::shared_ptr<ResidualDataAbstract> createData(DataCollectorAbstract* const data) override;
  std::shared_ptr<crocoddyl::ResidualModelBase> cloneAsDouble() const override;
  std::shared_ptr<crocoddyl::ResidualModelBase> cloneAsFloat() const override;
  void print(std::ostream& os) const override;

  pinocchio::FrameIndex get_id() const { return frame_id_; }

 private:
  std::shared_ptr<pinocchio::Model> pin_model_;
  pinocchio::FrameIndex frame_id_;
};

/// Workspace of ResidualModelFrameLinearVelocityWorld: the shared pinocchio data (forward
/// kinematics done by the differential model) and a private one for the derivatives.
struct ResidualDataFrameLinearVelocityWorld : public crocoddyl::ResidualDataAbstract {
  EIGEN_MAKE_ALIGNED_OPERATOR_NEW
  typedef crocoddyl::ResidualDataAbstract Base;
  typedef Eigen::Matrix<double, 6, Eigen::Dynamic> Matrix6xd;

  ResidualDataFrameLinearVelocityWorld(ResidualModelFrameLinearVelocityWorld* const model,
                                       crocoddyl::DataCollectorAbstract* const data);
  virtual ~ResidualDataFrameLinearVelocityWorld() = default;

  pinocchio::Data* shared_pinocchio;  ///< the differential model's pinocchio data
  pinocchio::Data pinocchio;          ///< private pinocchio data (derivatives)
  Matrix6xd dv_dq;                    ///< ∂v_local/∂q (6 × nv)
  Matrix6xd dv_dv;                    ///< ∂v_local/∂v = LOCAL frame Jacobian (6 × nv)
  Eigen::Matrix<double, 3, Eigen::Dynamic> dvl_dq;  ///< ∂v_l/∂q − [v_l]×·J_ω (3 × nv)
  VectorXd zero_a;                    ///< zero joint acceleration (nv)
};

/// The hard-constraint rows of a classical node as a residual (for crocoddyl's
/// ConstraintModelResidual): r = [S x; c .* u] (constraint_rows.hpp; the control rows in a
/// running node only), each row a fraction of its limit; Rx = [S; 0], Ru = [0; diag(c)]. C++
/// port of ffmpc_core.rigid_contact.ResidualModelConstraintRows.
class ResidualModelConstraintRows : public crocoddyl::ResidualModelAbstract {
 public:
  EIGEN_MAKE_ALIGNED_OPERATOR_NEW
  typedef crocoddyl::ResidualModelAbstract Base;
  typedef crocoddyl::ResidualDataAbstract ResidualDataAbstract;

  ResidualModelConstraintRows(std::shared_ptr<crocoddyl::StateAbstract> state, std::size_t nu,
                              const Eigen::MatrixXd& state_matrix,
                              const Eigen::VectorXd& control_scale, bool control);
  virtual ~ResidualModelConstraintRows() = default;

  void calc(const std::shared_ptr<ResidualDataAbstract>& data,
            const Eigen::Ref<const VectorXd>& x, const Eigen::Ref<const VectorXd>& u) override;
  void calc(const std::shared_ptr<ResidualDataAbstract>& data,
            const Eigen::Ref<const VectorXd>& x) override;
  void calcDiff(const std::shared_ptr<ResidualDataAbstract>& data,
                const Eigen::Ref<const VectorXd>& x,
                const Eigen::Ref<const VectorXd>& u) override;
  void calcDiff(const std::shared_ptr<ResidualDataAbstract>& data,
                const Eigen::Ref<const VectorXd>& x) override;
  std::shared_ptr<crocoddyl::ResidualModelBase> cloneAsDouble() const override;
  std::shared_ptr<crocoddyl::ResidualModelBase> cloneAsFloat() const override;
  void print(std::ostream& os) const override;

  const ConstraintRows& get_rows() const { return rows_; }

 private:
  ConstraintRows rows_;
};

}  // namespace ffmpc

#endif  // FFMPC_CPP_RESIDUALS_HPP_
