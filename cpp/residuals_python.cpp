// Python bindings of the custom residuals (residuals.hpp): ffmpc_core._native.
#include <boost/python.hpp>
#include <eigenpy/eigenpy.hpp>

#include "residuals.hpp"

namespace bp = boost::python;

namespace ffmpc {

namespace {

typedef crocoddyl::ResidualDataAbstract ResidualDataAbstract;
typedef Eigen::Ref<const Eigen::VectorXd> ConstRef;

void translate_model_error(const ModelError& error) {
  // ffmpc_core.errors is pure Python (no dependency): importing it here cannot recurse.
  bp::object cls = bp::import("ffmpc_core.errors").attr("ModelError");
  PyErr_SetString(cls.ptr(), error.what());
}

template <class Model>
void def_calc(bp::class_<Model, bp::bases<crocoddyl::ResidualModelAbstract>, std::shared_ptr<Model>>& cls) {
  typedef void (Model::*WithControl)(const std::shared_ptr<ResidualDataAbstract>&, const ConstRef&,
                                     const ConstRef&);
  typedef void (Model::*StateOnly)(const std::shared_ptr<ResidualDataAbstract>&, const ConstRef&);
  cls.def("calc", static_cast<WithControl>(&Model::calc), bp::args("self", "data", "x", "u"),
          "Residual at (x, u) into data.r.");
  cls.def("calc", static_cast<StateOnly>(&Model::calc), bp::args("self", "data", "x"),
          "Residual at x (no control).");
  cls.def("calcDiff", static_cast<WithControl>(&Model::calcDiff),
          bp::args("self", "data", "x", "u"), "Jacobians Rx, Ru at (x, u) (after calc).");
  cls.def("calcDiff", static_cast<StateOnly>(&Model::calcDiff), bp::args("self", "data", "x"),
          "Jacobian Rx at x (no control, after calc).");
  cls.def("createData", &Model::createData, bp::with_custodian_and_ward_postcall<0, 2>(),
          bp::args("self", "data"), "Create the residual data (data: the data collector).");
}

}  // namespace

void expose_residuals() {
  bp::register_exception_translator<ModelError>(&translate_model_error);
  typedef crocoddyl::StateMultibody StateMultibody;

  bp::class_<ResidualModelContactGravityTorque, bp::bases<crocoddyl::ResidualModelAbstract>,
             std::shared_ptr<ResidualModelContactGravityTorque>>
      grav(
      "ResidualModelContactGravityTorque",
      "Eq 25.3 in contact: r = tau - tau_g(q, lambda^r(x, u)), tau_g = g(q) - J^T lambda, N.m,\n"
      "with exact derivatives through the rigid contact force (C++ port of\n"
      "ffmpc_core.rigid_contact.ResidualModelContactGravityTorque).",
      bp::init<std::shared_ptr<StateMultibody>, std::size_t, bool, std::string>(
          bp::args("self", "state", "nu", "world_aligned", "contact_name"),
          "state: multibody state; nu: control dimension (== nv); world_aligned: the contact\n"
          "frame is LOCAL_WORLD_ALIGNED; contact_name: the contact in the differential\n"
          "model's ContactModelMultiple."));
  def_calc(grav);
  grav.add_property("world_aligned", &ResidualModelContactGravityTorque::get_world_aligned)
      .add_property("contact_name",
                    bp::make_function(&ResidualModelContactGravityTorque::get_contact_name,
                                      bp::return_value_policy<bp::copy_const_reference>()));

  bp::register_ptr_to_python<std::shared_ptr<ResidualDataContactGravityTorque>>();
  bp::class_<ResidualDataContactGravityTorque, bp::bases<crocoddyl::ResidualDataAbstract>,
             boost::noncopyable>("ResidualDataContactGravityTorque",
                                 "Workspace of ResidualModelContactGravityTorque.", bp::no_init)
      .add_property("dtau_g_dq",
                    bp::make_getter(&ResidualDataContactGravityTorque::dtau_g_dq,
                                    bp::return_internal_reference<>()),
                    "d tau_g / d q with the force fixed (after calcDiff), N.m/rad.");

  bp::class_<ResidualModelFrameLinearVelocityWorld, bp::bases<crocoddyl::ResidualModelAbstract>,
             std::shared_ptr<ResidualModelFrameLinearVelocityWorld>>
      vel("ResidualModelFrameLinearVelocityWorld",
          "Eq 25.5: linear velocity of a frame origin in world axes (LOCAL_WORLD_ALIGNED), m/s,\n"
          "with exact derivatives (C++ port of\n"
          "ffmpc_core.rigid_contact.ResidualModelFrameLinearVelocityWorld).",
          bp::init<std::shared_ptr<StateMultibody>, pinocchio::FrameIndex, std::size_t>(
              bp::args("self", "state", "frame_id", "nu"),
              "state: multibody state; frame_id: pinocchio frame; nu: control dimension."));
  def_calc(vel);
  vel.add_property("id", &ResidualModelFrameLinearVelocityWorld::get_id);

  bp::register_ptr_to_python<std::shared_ptr<ResidualDataFrameLinearVelocityWorld>>();
  bp::class_<ResidualDataFrameLinearVelocityWorld, bp::bases<crocoddyl::ResidualDataAbstract>,
             boost::noncopyable>("ResidualDataFrameLinearVelocityWorld",
                                 "Workspace of ResidualModelFrameLinearVelocityWorld.",
                                 bp::no_init);

  bp::class_<ResidualModelConstraintRows, bp::bases<crocoddyl::ResidualModelAbstract>,
             std::shared_ptr<ResidualModelConstraintRows>>
      rows("ResidualModelConstraintRows",
           "The hard-constraint rows of a classical node: r = [S x; c .* u] (the control rows\n"
           "in a running node only), each row a fraction of its limit (C++ port of\n"
           "ffmpc_core.rigid_contact.ResidualModelConstraintRows).",
           bp::init<std::shared_ptr<crocoddyl::StateAbstract>, std::size_t, Eigen::MatrixXd,
                    Eigen::VectorXd, bool>(
               bp::args("self", "state", "nu", "state_matrix", "control_scale", "control"),
               "state: a vector state (nx == ndx); nu: control dimension; state_matrix: S\n"
               "(rows x nx); control_scale: c (nu); control: whether there are control rows."));
  def_calc(rows);
  rows.add_property(
      "state_matrix",
      +[](const ResidualModelConstraintRows& m) { return Eigen::MatrixXd(m.get_rows().state_matrix); },
      "S (a copy).");
}

}  // namespace ffmpc
