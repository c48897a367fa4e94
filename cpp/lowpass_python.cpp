// Python bindings of the low-pass-filter integrator (lowpass.hpp): ffmpc_core._native.
#include <boost/python.hpp>
#include <eigenpy/eigenpy.hpp>

#include "lowpass.hpp"

namespace bp = boost::python;

namespace ffmpc {

namespace {

typedef crocoddyl::ActionDataAbstract ActionDataAbstract;
typedef Eigen::Ref<const Eigen::VectorXd> ConstRef;

}  // namespace

void expose_lowpass() {
  typedef IntegratedActionModelLPF Model;
  typedef IntegratedActionDataLPF Data;
  bp::class_<Model, bp::bases<crocoddyl::ActionModelAbstract>, std::shared_ptr<Model>>(
      "IntegratedActionModelLPF",
      "Eq 13-14 and 28 as a crocoddyl action model on x = (q, v, tau), u = w (C++ port of\n"
      "ffmpc_core.lowpass.IntegratedActionModelLPF: same step, cost and derivatives).",
      bp::init<std::shared_ptr<crocoddyl::DifferentialActionModelAbstract>, double, double, double,
               std::string, Eigen::MatrixXd, Eigen::VectorXd, bool, bp::optional<std::string>>(
          bp::args("self", "differential", "dt", "cutoff_frequency", "lowpass_input_weight",
                   "torque_cost", "constraint_matrix", "control_scale", "control_rows",
                   "torque_integration"),
          "differential: control tau (nu == nv == nq); dt: s; cutoff_frequency: f_c, Hz;\n"
          "lowpass_input_weight: c_w, 1/(N.m)^2; torque_cost: name of the eq 25.3 cost whose\n"
          "residual tau - tau_g gives tau_g (running nodes); constraint_matrix: the\n"
          "state-only constraint rows S on (q, v, tau) (0 rows: none); control_rows: also the\n"
          "rows control_scale .* w (running). Bounds in g_lb, g_ub. torque_integration:\n"
          "'current' (qdd at the state's tau, eq 14a) or 'next' (at tau+ = alpha tau +\n"
          "(1 - alpha) w, the authors' tau_plus_integration)."))
      .def<void (Model::*)(const std::shared_ptr<ActionDataAbstract>&, const ConstRef&,
                           const ConstRef&)>("calc", &Model::calc,
                                             bp::args("self", "data", "x", "u"),
                                             "Next state and cost at (x, u).")
      .def<void (Model::*)(const std::shared_ptr<ActionDataAbstract>&, const ConstRef&)>(
          "calc", &Model::calc, bp::args("self", "data", "x"),
          "Terminal: cost of the differential model at (q, v); xnext = x.")
      .def<void (Model::*)(const std::shared_ptr<ActionDataAbstract>&, const ConstRef&,
                           const ConstRef&)>("calcDiff", &Model::calcDiff,
                                             bp::args("self", "data", "x", "u"),
                                             "Derivatives at (x, u) (after calc).")
      .def<void (Model::*)(const std::shared_ptr<ActionDataAbstract>&, const ConstRef&)>(
          "calcDiff", &Model::calcDiff, bp::args("self", "data", "x"),
          "Terminal derivatives at x (after calc).")
      .def("createData", &Model::createData, bp::args("self"), "Create the data.")
      .add_property("differential",
                    bp::make_function(&Model::get_differential,
                                      bp::return_value_policy<bp::return_by_value>()),
                    "The wrapped differential model.")
      .add_property("dt", &Model::get_dt, "Delta t, s.")
      .add_property("cutoff_frequency", &Model::get_cutoff_frequency, "f_c, Hz.")
      .add_property("alpha", &Model::get_alpha, "alpha = exp(-2 pi f_c dt) of eq 13.")
      .add_property("lowpass_input_weight", &Model::get_lowpass_input_weight,
                    "c_w of eq 28, 1/(N.m)^2.")
      // crocoddyl 3.2.1 binds ng / ng_T on its Python wrapper class only: a C++ subclass's
      // Python object cannot read them there.
      .add_property("ng", +[](const Model& m) { return m.get_ng(); },
                    "Constraint rows of a node with a control (a running node).")
      .add_property("ng_T", +[](const Model& m) { return m.get_ng_T(); },
                    "Constraint rows of a call without a control (a terminal node).")
      .add_property("nv", &Model::get_nv, "Joint-velocity dimension.")
      .add_property("torque_integration", &Model::get_torque_integration,
                    "'current' or 'next': the torque qdd is computed at.")
      .add_property(
          "constraint_matrix",
          +[](const Model& m) { return Eigen::MatrixXd(m.get_constraint_rows().state_matrix); },
          "The state-only constraint rows S (a copy).")
      .add_property("torque_cost",
                    bp::make_function(&Model::get_torque_cost,
                                      bp::return_value_policy<bp::copy_const_reference>()),
                    "Name of the eq 25.3 cost of the differential model.");

  bp::register_ptr_to_python<std::shared_ptr<Data>>();
  bp::class_<Data, bp::bases<crocoddyl::ActionDataAbstract>, boost::noncopyable>(
      "IntegratedActionDataLPF", "Workspace of IntegratedActionModelLPF.",
      bp::init<Model*>(bp::args("self", "model"), "Create the data of model.")
          [bp::with_custodian_and_ward<1, 2>()])
      .add_property("differential",
                    bp::make_getter(&Data::differential,
                                    bp::return_value_policy<bp::return_by_value>()),
                    "The differential model's data.")
      .add_property("torque_residual",
                    bp::make_getter(&Data::torque_residual,
                                    bp::return_value_policy<bp::return_by_value>()),
                    "The eq 25.3 residual data of the differential data (None if absent).")
      .add_property("lowpass_residual",
                    bp::make_getter(&Data::lowpass_residual, bp::return_internal_reference<>()),
                    "w - tau_g of eq 28 after calc, N.m.")
      .add_property("applied_torque",
                    bp::make_getter(&Data::applied_torque, bp::return_internal_reference<>()),
                    "tau_a, the torque qdd was computed at, after calc, N.m.")
      .add_property("dtau_g_dx",
                    bp::make_getter(&Data::dtau_g_dx, bp::return_internal_reference<>()),
                    "d tau_g / dx (nv x 3nv) after calcDiff.");
}

}  // namespace ffmpc
