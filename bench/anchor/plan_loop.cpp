// The compiled anchor of bench/bench_anchor.py: the paper's planner loop (Figure 2) written with
// Pinocchio and Eigen only, no engine code. Per step: the GJM from Pinocchio's frame Jacobian and
// centroidal momentum map (J_m - J_b A_b^-1 A_m, zero momentum), Eigen's JacobiSVD and the
// adaptive damping of eq. 16, q += qd dt, and the carrier's attitude advanced along the joint line
// by the same fourth-order Magnus step on Simpson's nodes as the engine (sub-steps of at most
// 0.25 rad of joint travel); the carrier's position keeps the system CoM where it started.
//
// Input (stdin, whitespace-separated): n; base mass, inertia (9), b0 (3); per link: mass,
// inertia (9), axis (3), a (3), b (3); C_e (9); q0 (n); N; dt; lambda_max; epsilon; repeats;
// twists (N+1 x 6, world [v; w]); p_des (N+1 x 3).
// Output: the final joints, the largest position error, and the seconds per plan-step (the best
// of the repeats).
#include <pinocchio/multibody.hpp>
#include <pinocchio/spatial.hpp>
#include <pinocchio/algorithm/center-of-mass.hpp>
#include <pinocchio/algorithm/centroidal.hpp>
#include <pinocchio/algorithm/frames.hpp>
#include <pinocchio/algorithm/jacobian.hpp>
#include <pinocchio/algorithm/kinematics.hpp>

#include <Eigen/SVD>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <vector>

using Eigen::Matrix3d;
using Eigen::MatrixXd;
using Eigen::Vector3d;
using Eigen::VectorXd;

static Matrix3d read3x3() {
  Matrix3d m;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) std::cin >> m(r, c);
  return m;
}

static Vector3d read3() {
  Vector3d v;
  std::cin >> v[0] >> v[1] >> v[2];
  return v;
}

struct Planner {
  pinocchio::Model model;
  pinocchio::Data data;
  pinocchio::FrameIndex ee;
  int n;
  Vector3d com_w;
  MatrixXd J, Jg;
  Planner(pinocchio::Model m, pinocchio::FrameIndex frame, int joints)
      : model(m), data(m), ee(frame), n(joints), J(6, m.nv), Jg(6, joints) {}

  // The configuration of joints q with the carrier's attitude A0 and its CoM at the origin.
  VectorXd config(const VectorXd& q, const Matrix3d& A0) const {
    VectorXd x(model.nq);
    Eigen::Quaterniond quat(A0);
    x.head<3>().setZero();
    x.segment<4>(3) = quat.coeffs();
    x.tail(n) = q;
    return x;
  }

  // The carrier's twist (LOCAL frame: [v; w] in the carrier's axes) for joint rates qd at x.
  Eigen::Matrix<double, 6, 1> base_twist(const VectorXd& x, const VectorXd& qd) {
    const auto& Ag = pinocchio::computeCentroidalMap(model, data, x);
    return -Ag.leftCols<6>().partialPivLu().solve(Ag.rightCols(n) * qd);
  }

  Vector3d base_rate(const VectorXd& q, const VectorXd& qd) {
    return base_twist(config(q, Matrix3d::Identity()), qd).tail<3>();  // independent of the attitude
  }

  // The world pose of the end effector and the GJM (world axes) at q, A0, the system CoM at com_w.
  void gjm(const VectorXd& q, const Matrix3d& A0, Vector3d& p_e) {
    VectorXd x = config(q, A0);
    Vector3d c = pinocchio::centerOfMass(model, data, x);
    x.head<3>() = com_w - c;
    pinocchio::computeJointJacobians(model, data, x);
    pinocchio::updateFramePlacements(model, data);
    J.setZero();
    pinocchio::getFrameJacobian(model, data, ee, pinocchio::LOCAL_WORLD_ALIGNED, J);
    const auto& Ag = pinocchio::computeCentroidalMap(model, data, x);
    // the free-flyer's velocity is in its LOCAL frame: J's base columns act on it
    Jg = J.rightCols(n) - J.leftCols<6>() * Ag.leftCols<6>().partialPivLu().solve(Ag.rightCols(n));
    p_e = data.oMf[ee].translation();
  }
};

int main() {
  std::ios::sync_with_stdio(false);
  int n;
  std::cin >> n;
  pinocchio::Model model;
  double base_mass;
  std::cin >> base_mass;
  Matrix3d base_inertia = read3x3();
  Vector3d offset = read3();
  auto parent = model.addJoint(0, pinocchio::JointModelFreeFlyer(), pinocchio::SE3::Identity(), "base");
  model.appendBodyToJoint(parent, pinocchio::Inertia(base_mass, Vector3d::Zero(), base_inertia), pinocchio::SE3::Identity());
  for (int i = 0; i < n; ++i) {
    double mass;
    std::cin >> mass;
    Matrix3d inertia = read3x3();
    Vector3d axis = read3(), a = read3(), b = read3();
    parent = model.addJoint(parent, pinocchio::JointModelRevoluteUnaligned(axis), pinocchio::SE3(Matrix3d::Identity(), offset),
                            "joint" + std::to_string(i + 1));
    model.appendBodyToJoint(parent, pinocchio::Inertia(mass, a, inertia), pinocchio::SE3::Identity());
    offset = a + b;
  }
  Matrix3d C_e = read3x3();
  auto frame = model.addFrame(pinocchio::Frame("ee", parent, 0, pinocchio::SE3(C_e, offset), pinocchio::OP_FRAME));
  VectorXd q0(n);
  for (int j = 0; j < n; ++j) std::cin >> q0[j];
  int N, repeats;
  double dt, lam_max, eps;
  std::cin >> N >> dt >> lam_max >> eps >> repeats;
  std::vector<Eigen::Matrix<double, 6, 1>> twists(N + 1);
  std::vector<Vector3d> p_des(N + 1);
  for (auto& t : twists)
    for (int r = 0; r < 6; ++r) std::cin >> t[r];
  for (auto& p : p_des) p = read3();

  Planner planner(model, frame, n);
  VectorXd q(n), qd(n), q_sub(n);
  double best = 1e300, pos_max = 0.0;
  for (int rep = 0; rep < repeats; ++rep) {
    auto start = std::chrono::steady_clock::now();
    q = q0;
    Matrix3d A0 = Matrix3d::Identity();
    // the carrier's CoM starts at the origin; the system CoM stays where that puts it
    planner.com_w = pinocchio::centerOfMass(model, planner.data, planner.config(q, A0));
    pos_max = 0.0;
    Vector3d p_e;
    for (int k = 0; k <= N; ++k) {
      planner.gjm(q, A0, p_e);
      pos_max = std::max(pos_max, (p_e - p_des[k]).norm());
      Eigen::JacobiSVD<MatrixXd> svd(planner.Jg, Eigen::ComputeThinU | Eigen::ComputeThinV);
      const VectorXd& s = svd.singularValues();
      VectorXd gain(s.size());
      for (int i = 0; i < s.size(); ++i) {
        double lam = s[i] < eps ? 0.5 * lam_max * (1.0 + std::cos(M_PI * s[i] / eps)) : 0.0;
        gain[i] = s[i] / (s[i] * s[i] + lam * lam);
      }
      qd = svd.matrixV() * (gain.asDiagonal() * (svd.matrixU().transpose() * twists[k]));
      if (k == N) break;
      double travel = 0.0;
      for (int j = 0; j < n; ++j) travel = std::max(travel, std::abs(qd[j]) * dt / 0.25);
      int S = std::min(64, std::max(1, (int)std::ceil(travel)));
      double h = dt / S;
      Vector3d wa = planner.base_rate(q, qd);
      for (int sub = 0; sub < S; ++sub) {
        q_sub = q + qd * ((sub + 0.5) * h);
        Vector3d wm = planner.base_rate(q_sub, qd);
        q_sub = q + qd * ((sub + 1) * h);
        Vector3d wb = planner.base_rate(q_sub, qd);
        Vector3d phi = h / 6.0 * (wa + 4.0 * wm + wb) + h * h / 12.0 * wa.cross(wb);
        A0 = A0 * pinocchio::exp3(phi);
        wa = wb;
      }
      q += qd * dt;
    }
    double elapsed = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    best = std::min(best, elapsed);
  }
  std::printf("q");
  for (int j = 0; j < n; ++j) std::printf(" %.17g", q[j]);
  std::printf("\npos_max %.17g\nseconds_per_step %.6e\n", pos_max, best / (N + 1));
  return 0;
}
