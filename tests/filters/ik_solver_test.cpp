// Tests for the warm-started IK: exactness of the tree elimination against a dense
// solve, recovery of known poses, robustness, status values and zero allocation.
#include "filters/ik_solver.hpp"

#include <gtest/gtest.h>

#include <random>

#include "filters/cleanup_options.hpp"
#include "filters/pose_error.hpp"
#include "filters/rotation.hpp"
#include "formats/take_frames.hpp"
#include "tests/support/allocation_counter.hpp"
#include "tests/support/test_takes.hpp"

namespace mocapd {
namespace {

class IkSolverTest : public ::testing::Test {
 protected:
  IkSolverTest() : fixture_(testing::MakeHumanoidFixture("mixed", 6.0, 120.0)) {}

  // Observations of frame f of the fixture's take.
  void Observe(int f) {
    observed_.resize(static_cast<size_t>(markers().num_markers()));
    weights_.resize(observed_.size());
    const TakeMarkerMap map(markers(), fixture_.take);
    map.Observe(fixture_.take, f, observed_, weights_);
  }
  // The dense Gauss-Newton system (J'WJ + P) dq = J'Wr - g_P in IntegratePose's axes.
  void DenseNormalEquations(const IkOptions& options, const Pose& pose, Eigen::MatrixXd* H,
                            Eigen::VectorXd* g) const {
    KinematicsWorkspace ws(skeleton());
    ForwardKinematics(skeleton(), pose, &ws);
    const Eigen::MatrixXd J = MarkerJacobian(skeleton(), markers(), ws);
    Eigen::VectorXd r(J.rows()), w(J.rows());
    for (int m = 0; m < markers().num_markers(); ++m) {
      r.segment<3>(3 * m) =
          observed_[static_cast<size_t>(m)] - EvaluateMarker(markers().marker(m), ws);
      w.segment<3>(3 * m).setConstant(weights_[static_cast<size_t>(m)]);
    }
    Eigen::VectorXd mask = Eigen::VectorXd::Zero(skeleton().num_dofs()),
                    rest_error(skeleton().num_dofs());
    for (int j = 0; j < skeleton().num_joints(); ++j) {
      const int k = skeleton().dof_offset(j);
      if (skeleton().joint(j).type == JointType::kBall) mask.segment<3>(k).setOnes();
      if (skeleton().joint(j).type == JointType::kFree) mask.segment<3>(k + 3).setOnes();
    }
    PoseDifference(skeleton(), RestPose(skeleton()), pose, rest_error);
    *H = J.transpose() * w.asDiagonal() * J;
    H->diagonal() += (options.temporal_weight + options.rest_weight) * mask +
                     Eigen::VectorXd::Constant(skeleton().num_dofs(), 1e-12);
    *g = J.transpose() * w.asDiagonal() * r - options.rest_weight * mask.cwiseProduct(rest_error);
  }
  // Observations of frame 0 with every joint below the root turned by up to 1.5 rad per
  // axis: a pose far from the rest pose a cold start begins at.
  void ObserveTurnedPose(std::mt19937_64& rng) {
    std::uniform_real_distribution<double> u(-1.5, 1.5);
    Pose pose = fixture_.motion[0];
    for (size_t j = 1; j < pose.rotation.size(); ++j)
      pose.rotation[j] = pose.rotation[j] * ExpRotation(Vec3(u(rng), u(rng), u(rng)));
    KinematicsWorkspace ws(skeleton());
    ForwardKinematics(skeleton(), pose, &ws);
    for (int m = 0; m < markers().num_markers(); ++m)
      observed_[static_cast<size_t>(m)] = EvaluateMarker(markers().marker(m), ws);
  }
  const Skeleton& skeleton() const { return *fixture_.skeleton; }
  const MarkerSet& markers() const { return *fixture_.markers; }

  testing::HumanoidFixture fixture_;
  std::vector<Vec3> observed_;
  std::vector<double> weights_;
};

TEST_F(IkSolverTest, TreeEliminationStepEqualsDenseGaussNewtonSolve) {
  IkOptions options;
  options.rest_weight = 1e-3;  // make the prior terms visible in the comparison
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u(-0.3, 0.3);
  for (int trial = 0; trial < 5; ++trial) {
    Observe(100 * trial);
    weights_[3] = 0.0;  // a missing marker
    weights_[7] = 2.5;  // a trusted one
    // Linearise away from the truth so the residuals are large.
    Pose pose = fixture_.motion[static_cast<size_t>(100 * trial)];
    for (auto& q : pose.rotation) q = q * ExpRotation(Vec3(u(rng), u(rng), u(rng)));
    const double damping = 0.0;
    IkState state(skeleton(), markers());
    Eigen::VectorXd dq;
    ASSERT_TRUE(ComputeIkStep(skeleton(), markers(), options, observed_, weights_, pose, damping,
                              &state, &dq));

    Eigen::MatrixXd H;
    Eigen::VectorXd g;
    DenseNormalEquations(options, pose, &H, &g);
    const Eigen::VectorXd dense = H.ldlt().solve(g);
    EXPECT_LT((dq - dense).norm(), 1e-8 * std::max(1.0, dense.norm())) << "trial " << trial;
  }
}

TEST_F(IkSolverTest, DampedStepStillDecreasesTheLinearisedCost) {
  Observe(250);
  Pose pose = fixture_.motion[250];
  for (auto& q : pose.rotation) q = q * ExpRotation(Vec3(0.1, -0.05, 0.08));
  IkState state(skeleton(), markers());
  Eigen::MatrixXd H;
  Eigen::VectorXd g;
  DenseNormalEquations(IkOptions{}, pose, &H, &g);
  auto model = [&](const Eigen::VectorXd& dq) { return 0.5 * dq.dot(H * dq) - g.dot(dq); };
  Eigen::VectorXd gauss_newton, damped;
  ASSERT_TRUE(ComputeIkStep(skeleton(), markers(), IkOptions{}, observed_, weights_, pose, 0.0,
                            &state, &gauss_newton));
  ASSERT_TRUE(ComputeIkStep(skeleton(), markers(), IkOptions{}, observed_, weights_, pose, 10.0,
                            &state, &damped));
  EXPECT_LT(model(damped), 0.0);                  // downhill
  EXPECT_LE(model(gauss_newton), model(damped));  // the undamped step is the model's minimum
  EXPECT_LT(damped.norm(), 2.0 * gauss_newton.norm());
}

TEST_F(IkSolverTest, ColdStartRecoversAPoseFromCleanMarkers) {
  IkOptions options;
  options.temporal_weight = 0.0;
  options.rest_weight = 0.0;
  options.function_tolerance = 1e-12;
  for (int f : {0, 150, 400, 650}) {
    Observe(f);
    IkState dut(skeleton(), markers());
    const IkSummary summary = SolveIk(skeleton(), markers(), options, observed_, weights_, &dut);
    EXPECT_TRUE(summary.cold_start);
    EXPECT_EQ(summary.status, IkStatus::kConverged) << to_string(summary.status);
    EXPECT_LT(summary.rms_residual_m, 1e-6);
    KinematicsWorkspace truth(skeleton());
    ForwardKinematics(skeleton(), fixture_.motion[static_cast<size_t>(f)], &truth);
    for (int j = 0; j < skeleton().num_joints(); ++j)
      EXPECT_LT((truth.p_WJ[static_cast<size_t>(j)] - dut.kinematics().p_WJ[static_cast<size_t>(j)])
                    .norm(),
                1e-5)
          << "frame " << f << " joint " << skeleton().joint(j).name;
  }
}

TEST_F(IkSolverTest, WarmStartedTrackingIsAccurateOnCleanMarkers) {
  IkState dut(skeleton(), markers());
  PoseErrorAccumulator errors(skeleton());
  KinematicsWorkspace truth(skeleton());
  int iterations = 0;
  const IkOptions options;
  for (int f = 0; f < fixture_.take.num_frames; ++f) {
    Observe(f);
    const IkSummary summary = SolveIk(skeleton(), markers(), options, observed_, weights_, &dut);
    ASSERT_NE(summary.status, IkStatus::kNumericalFailure);
    if (f > 0) iterations += summary.iterations;
    ForwardKinematics(skeleton(), fixture_.motion[static_cast<size_t>(f)], &truth);
    errors.Add(truth, dut.kinematics());
  }
  EXPECT_LT(errors.mean_position_error_m(), 1e-4);
  EXPECT_LT(errors.max_position_error_m(), 5e-3);
  EXPECT_LT(errors.mean_rotation_error_rad(), 0.2 * M_PI / 180);
  EXPECT_LT(static_cast<double>(iterations) / (fixture_.take.num_frames - 1), 4.0);
}

TEST_F(IkSolverTest, NoiseDoesNotMakeJointsDrift) {
  fixture_ = testing::MakeHumanoidFixture("mixed", 6.0, 120.0, 1e-3);
  IkState dut(skeleton(), markers());
  PoseErrorAccumulator errors(skeleton());
  KinematicsWorkspace truth(skeleton());
  for (int f = 0; f < fixture_.take.num_frames; ++f) {
    Observe(f);
    SolveIk(skeleton(), markers(), IkOptions{}, observed_, weights_, &dut);
    ForwardKinematics(skeleton(), fixture_.motion[static_cast<size_t>(f)], &truth);
    errors.Add(truth, dut.kinematics());
  }
  EXPECT_LT(errors.mean_rotation_error_rad(), 2.0 * M_PI / 180);
  int worst = -1;
  EXPECT_LT(errors.worst_joint_rotation_quantile_rad(0.99, &worst), 10.0 * M_PI / 180)
      << skeleton().joint(worst).name;
}

TEST_F(IkSolverTest, MissingMarkersAreIgnored) {
  Observe(200);
  IkState reference(skeleton(), markers());
  SolveIk(skeleton(), markers(), IkOptions{}, observed_, weights_, &reference);
  // Corrupt some markers wildly but mark them missing (weight 0 or NaN position).
  observed_[0] += Vec3(1, 1, 1);
  weights_[0] = 0.0;
  observed_[5] = Vec3::Constant(kNaN);
  IkState dut(skeleton(), markers());
  const IkSummary summary = SolveIk(skeleton(), markers(), IkOptions{}, observed_, weights_, &dut);
  EXPECT_EQ(summary.markers_used, markers().num_markers() - 2);
  for (int j = 0; j < skeleton().num_joints(); ++j)
    EXPECT_LT((reference.kinematics().p_WJ[static_cast<size_t>(j)] -
               dut.kinematics().p_WJ[static_cast<size_t>(j)])
                  .norm(),
              2e-3);
}

TEST_F(IkSolverTest, HuberLossResistsAWildMarker) {
  Observe(300);
  observed_[10] += Vec3(0.0, 0.4, 0.0);  // a 40 cm pop
  KinematicsWorkspace truth(skeleton());
  ForwardKinematics(skeleton(), fixture_.motion[300], &truth);
  auto worst_joint_error = [&](const IkOptions& options) {
    IkState state(skeleton(), markers());
    SolveIk(skeleton(), markers(), options, observed_, weights_, &state);
    double worst = 0.0;
    for (int j = 0; j < skeleton().num_joints(); ++j)
      worst = std::max(worst, (truth.p_WJ[static_cast<size_t>(j)] -
                               state.kinematics().p_WJ[static_cast<size_t>(j)])
                                  .norm());
    return worst;
  };
  IkOptions plain;
  IkOptions robust;
  robust.huber_delta_m = 0.01;
  const double plain_error = worst_joint_error(plain);
  const double robust_error = worst_joint_error(robust);
  EXPECT_GT(plain_error, 0.02);
  EXPECT_LT(robust_error, 0.5 * plain_error);
}

TEST_F(IkSolverTest, TooFewMarkersHoldsTheLastSolution) {
  IkState dut(skeleton(), markers());
  Observe(0);
  SolveIk(skeleton(), markers(), IkOptions{}, observed_, weights_, &dut);
  const Pose before = dut.pose();
  std::fill(weights_.begin(), weights_.end(), 0.0);
  weights_[0] = weights_[1] = 1.0;
  const IkSummary summary = SolveIk(skeleton(), markers(), IkOptions{}, observed_, weights_, &dut);
  EXPECT_EQ(summary.status, IkStatus::kTooFewMarkers);
  EXPECT_EQ(summary.iterations, 0);
  for (size_t j = 0; j < before.rotation.size(); ++j)
    EXPECT_TRUE(before.rotation[j].isApprox(dut.pose().rotation[j]));
}

TEST_F(IkSolverTest, ResetMakesTheNextSolveCold) {
  IkState dut(skeleton(), markers());
  Observe(0);
  EXPECT_TRUE(SolveIk(skeleton(), markers(), IkOptions{}, observed_, weights_, &dut).cold_start);
  Observe(1);
  EXPECT_FALSE(SolveIk(skeleton(), markers(), IkOptions{}, observed_, weights_, &dut).cold_start);
  dut.Reset();
  EXPECT_FALSE(dut.has_solution());
  Observe(2);
  EXPECT_TRUE(SolveIk(skeleton(), markers(), IkOptions{}, observed_, weights_, &dut).cold_start);
}

TEST_F(IkSolverTest, SolveAllocatesNothingAfterWarmUp) {
  IkState dut(skeleton(), markers());
  IkOptions options;
  options.huber_delta_m = 0.02;                   // exercise the robust path too
  options.cold_start_least_squares_first = true;  // and the cold start's second start
  for (int f = 0; f < 5; ++f) {
    Observe(f);
    SolveIk(skeleton(), markers(), options, observed_, weights_, &dut);
  }
  const TakeMarkerMap map(markers(), fixture_.take);
  size_t allocations = 0;
  {
    testing::ScopedAllocationCounter counter;
    for (int f = 5; f < 200; ++f) {
      map.Observe(fixture_.take, f, observed_, weights_);
      if (f == 50) weights_[4] = 0.0;
      if (f == 60) {
        std::fill(weights_.begin(), weights_.end(), 0.0);  // too few markers
      }
      if (f == 100) dut.Reset();  // the cold-start path (Kabsch alignment) too
      SolveIk(skeleton(), markers(), options, observed_, weights_, &dut);
    }
    allocations = counter.count();
  }
  EXPECT_EQ(allocations, 0u);
}

TEST(IkOptionsTest, ValidateNamesTheBadField) {
  IkOptions options;
  options.max_iterations = 0;
  try {
    options.Validate();
    FAIL();
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("max_iterations"), std::string::npos);
  }
  options = IkOptions{};
  options.huber_delta_m = -1.0;
  EXPECT_THROW(options.Validate(), std::invalid_argument);
}

// A robust loss seen from the aligned rest pose takes the clean markers of a limb that
// starts far from them for outliers, and can settle with the limb beside them (a Bandai
// take's clavicle and upper arm 5-11 cm off three clean markers). Whole-body poses with
// every joint turned up to 1.5 rad from a frame of the take: the robust cold start must
// fit them all (5 of 200 stayed in such a minimum before it began with least squares).
TEST_F(IkSolverTest, RobustColdStartFitsLimbsThatStartFarFromTheirMarkers) {
  IkOptions robust;
  robust.huber_delta_m = 0.004;
  robust.cold_start_least_squares_first = true;
  std::mt19937_64 rng(11);
  Observe(0);
  int stuck = 0;
  for (int trial = 0; trial < 200; ++trial) {
    ObserveTurnedPose(rng);
    IkState state(skeleton(), markers());
    const IkSummary summary = SolveIk(skeleton(), markers(), robust, observed_, weights_, &state);
    ASSERT_TRUE(summary.cold_start);
    if (summary.rms_residual_m > 0.002) {
      ++stuck;
      ADD_FAILURE() << "trial " << trial << ": " << summary.rms_residual_m * 1e3
                    << " mm RMS after a cold start";
    }
  }
  EXPECT_EQ(stuck, 0);
}

// The second start must never cost the first: where least squares follows a wild marker
// to a worse minimum, the robust start's solution is kept, exactly; where it finds a
// better one (a limb the robust start left beside its markers), that one is kept. Every
// pose as above, with one marker 40 cm off.
TEST_F(IkSolverTest, RobustColdStartKeepsTheBetterOfItsTwoStarts) {
  IkOptions robust_only;
  robust_only.huber_delta_m = 0.004;
  IkOptions both = robust_only;
  both.cold_start_least_squares_first = true;
  std::mt19937_64 rng(11);
  Observe(0);
  int improved = 0;
  for (int trial = 0; trial < 100; ++trial) {
    ObserveTurnedPose(rng);
    observed_[static_cast<size_t>(trial) % observed_.size()] += Vec3(0.0, 0.4, 0.0);
    IkState a(skeleton(), markers()), b(skeleton(), markers());
    const IkSummary first = SolveIk(skeleton(), markers(), robust_only, observed_, weights_, &a);
    const IkSummary best = SolveIk(skeleton(), markers(), both, observed_, weights_, &b);
    ASSERT_LE(best.final_cost, first.final_cost) << "trial " << trial;
    if (best.final_cost < first.final_cost) {
      ++improved;
    } else {
      // The first start's solution, its fitted markers included.
      for (size_t j = 0; j < a.pose().rotation.size(); ++j)
        EXPECT_TRUE(a.pose().rotation[j].coeffs() == b.pose().rotation[j].coeffs()) << trial;
      for (size_t m = 0; m < observed_.size(); ++m)
        EXPECT_EQ(a.predicted_markers()[m], b.predicted_markers()[m]) << trial;
    }
  }
  EXPECT_GT(improved, 0);
}

}  // namespace
// A cold solve with a thigh and shin unseen leaves the knee wherever the rest pose's
// straight leg happened to bend; nothing was published yet, so the unseen-knee rule puts
// it all the way onto the axis the foot asks for, not merely back within its tolerance
// at the warm-start rate (a Bandai run's first frame: 29.5 -> 2.5 cm).
TEST_F(IkSolverTest, AColdSolvesUnseenKneeIsTurnedOntoItsAxis) {
  const CleanupOptions cleanup;
  const IkOptions options = WithUnseenKneeRule(cleanup.final_ik, cleanup);
  const int hip = skeleton().FindJoint("LeftUpLeg")->value;
  const auto knee = static_cast<size_t>(skeleton().FindJoint("LeftLeg")->value);
  KinematicsWorkspace solved(skeleton()), truth(skeleton());
  double worst = 0.0;
  int bent_frames = 0;
  for (int f = 0; f < fixture_.take.num_frames; f += 5) {
    ForwardKinematics(skeleton(), fixture_.motion[static_cast<size_t>(f)], &truth);
    const Vec3 thigh = truth.p_WJ[knee] - truth.p_WJ[static_cast<size_t>(hip)];
    const Vec3 shin =
        truth.p_WJ[static_cast<size_t>(skeleton().FindJoint("LeftFoot")->value)] - truth.p_WJ[knee];
    if (thigh.normalized().dot(shin.normalized()) > std::cos(0.6)) continue;  // 35 deg bent
    ++bent_frames;
    Observe(f);
    for (int m = 0; m < markers().num_markers(); ++m)
      if (markers().primary_joint(m) == hip || markers().primary_joint(m) == static_cast<int>(knee))
        weights_[static_cast<size_t>(m)] = 0.0;
    IkState state(skeleton(), markers());
    const IkSummary summary = SolveIk(skeleton(), markers(), options, observed_, weights_, &state);
    ASSERT_TRUE(summary.cold_start);
    ForwardKinematics(skeleton(), state.pose(), &solved);
    worst = std::max(worst, (solved.p_WJ[knee] - truth.p_WJ[knee]).norm());
  }
  ASSERT_GT(bent_frames, 5);
  EXPECT_LT(worst, 0.03) << "over " << bent_frames << " frames";
}

}  // namespace mocapd
