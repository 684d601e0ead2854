// Levenberg-Marquardt IK with leaf-to-root elimination over the joint tree.
//
// Each joint J keeps a quadratic 1/2 V' Q V - b' V in its body's twist V = (w, v), where
// v is the velocity of the world point at J's pivot c_J, so a point x on the body moves
// at A(x - c_J) V with A(y) = [-[y]x  I]. Steps are taken about world axes at the pivot,
// which makes each joint's motion subspace S a selection of unit columns.
//
// Eliminating joint c (parent p, d = c_c - c_p): its twist is V_c = X V_p + S dq_c with
// X = [I 0; -[d]x I] (the parent's twist seen at c's pivot). A marker blended between c
// and p moves by  B V_p + C S dq_c  with C = w_c A(x_c - c_c) and
// B = w_p A(x_p - c_p) + w_c A(x_c - c_p). Minimising over dq_c leaves a quadratic in V_p
// that is added to the parent's (Q, b); the forward sweep recovers dq_c = k - K V_p.
// With zero damping this is exactly the dense Gauss-Newton step (J'WJ + P) dq = J'Wr - g_P;
// the Marquardt damping scales each joint's own (Schur-reduced) diagonal.
#include "filters/ik_solver.hpp"

#include <Eigen/Cholesky>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "filters/rotation.hpp"

namespace mocapd {
namespace {

using JointBlock = IkState::JointBlock;

// Adds the rigid markers' moments (sum over markers of A(x)' A(x) and A(x)' r, with
// A(x) = [-[x]x I]) to the joint's quadratic.
void AddMoments(JointBlock* blk) {
  if (blk->m0 == 0.0) return;
  const Mat3 X = Skew(blk->m1);
  blk->Q.topLeftCorner<3, 3>() += blk->M2.trace() * Mat3::Identity() - blk->M2;
  blk->Q.topRightCorner<3, 3>() += X;
  blk->Q.bottomLeftCorner<3, 3>() -= X;
  blk->Q.bottomRightCorner<3, 3>().diagonal().array() += blk->m0;
  blk->b.head<3>() += blk->xr;
  blk->b.tail<3>() += blk->wr;
}

double RobustCost(double r_norm, double delta) {
  if (delta <= 0.0 || r_norm <= delta) return 0.5 * r_norm * r_norm;
  return delta * (r_norm - 0.5 * delta);
}

double RobustWeight(double r_norm, double delta) {
  if (delta <= 0.0 || r_norm <= delta) return 1.0;
  return delta / r_norm;
}

bool UsableMarker(const Vec3& y, double weight) { return weight > 0.0 && y.allFinite(); }

// Marker cost of the current pose (robust loss), filling predicted.
double MarkerCost(const MarkerSet& markers, const IkOptions& options,
                  std::span<const Vec3> observed, std::span<const double> weights,
                  const KinematicsWorkspace& ws, std::span<Vec3> predicted) {
  double cost = 0.0;
  for (int m = 0; m < markers.num_markers(); ++m) {
    const auto um = static_cast<size_t>(m);
    predicted[um] = EvaluateMarker(markers.marker(m), ws);
    if (!UsableMarker(observed[um], weights[um])) continue;
    const Vec3 r = observed[um] - predicted[um];
    // Plain least squares needs no square root.
    cost += weights[um] * (options.huber_delta_m > 0.0 ? RobustCost(r.norm(), options.huber_delta_m)
                                                       : 0.5 * r.squaredNorm());
  }
  return cost;
}

// The priors live in the tangent space of the frame's warm start: x is the total step
// taken so far this frame, rest_error the rest-pose deviation at the warm start, both
// per DOF (zero on translations). To first order x = q (-) q_prior and
// rest_error + x = q (-) q_rest, which saves two logarithms per joint per evaluation.
double PriorCost(double temporal_weight, double rest_weight, const Eigen::VectorXd& mask,
                 const Eigen::VectorXd& rest_error, const Eigen::VectorXd& x) {
  return 0.5 * (temporal_weight * (mask.array() * x.array().square()).sum() +
                rest_weight * (mask.array() * (rest_error + x).array().square()).sum());
}

// Adds each marker's contribution to its joint's block (and the blend blocks), with
// twists referred to each joint's pivot.
void AccumulateMarkers(const MarkerSet& markers, const IkOptions& options,
                       std::span<const Vec3> observed, std::span<const double> weights,
                       std::span<const Vec3> predicted, const KinematicsWorkspace& ws,
                       std::vector<JointBlock>* blocks) {
  for (int m = 0; m < markers.num_markers(); ++m) {
    const auto um = static_cast<size_t>(m);
    if (!UsableMarker(observed[um], weights[um])) continue;
    const Vec3 r = observed[um] - predicted[um];
    const double w = options.huber_delta_m > 0.0
                         ? weights[um] * RobustWeight(r.norm(), options.huber_delta_m)
                         : weights[um];
    const MarkerDefinition& def = markers.marker(m);
    const MarkerAttachment& a0 = def.attachments[0];
    const auto j0 = static_cast<size_t>(a0.joint);
    JointBlock& blk = (*blocks)[j0];
    if (def.num_attachments == 1) {
      // Moments only: the 6x6 block is built once per joint (see AddMoments).
      const Vec3 x = predicted[um] - ws.p_WJ[j0];
      const Vec3 wx = w * x;
      blk.m0 += w;
      blk.m1 += wx;
      blk.M2.noalias() += wx * x.transpose();
      blk.xr += wx.cross(r);
      blk.wr += w * r;
      continue;
    }
    const MarkerAttachment& a1 = def.attachments[1];
    const auto j1 = static_cast<size_t>(a1.joint);
    const Vec3 x0 = ws.R_WJ[j0] * a0.offset + ws.p_WJ[j0];
    const Vec3 x1 = ws.R_WJ[j1] * a1.offset + ws.p_WJ[j1];
    // C = w_c A(gamma) with gamma = x0 - c_c, and since the weights sum to one,
    // B = w_p A(x1 - c_p) + w_c A(x0 - c_p) = A(beta) with beta the blended point about c_p.
    // Then B'B = P(beta), C'C = w_c^2 P(gamma), B'C = w_c M(beta, gamma) with
    // P(y) = [|y|^2 I - yy', [y]x; -[y]x, I] and M(b, g) = [(b.g) I - g b', [b]x; -[g]x, I].
    const double wc = a0.weight;
    const Vec3 gamma = x0 - ws.p_WJ[j0];
    const Vec3 beta = a1.weight * (x1 - ws.p_WJ[j1]) + wc * (x0 - ws.p_WJ[j1]);
    const Mat3 Sb = Skew(beta), Sg = Skew(gamma);
    blk.BB.topLeftCorner<3, 3>().noalias() +=
        w * (beta.squaredNorm() * Mat3::Identity() - beta * beta.transpose());
    blk.BB.topRightCorner<3, 3>() += w * Sb;
    blk.BB.bottomLeftCorner<3, 3>() -= w * Sb;
    blk.BB.bottomRightCorner<3, 3>().diagonal().array() += w;
    const double wg = w * wc * wc;
    blk.GG.topLeftCorner<3, 3>().noalias() +=
        wg * (gamma.squaredNorm() * Mat3::Identity() - gamma * gamma.transpose());
    blk.GG.topRightCorner<3, 3>() += wg * Sg;
    blk.GG.bottomLeftCorner<3, 3>() -= wg * Sg;
    blk.GG.bottomRightCorner<3, 3>().diagonal().array() += wg;
    const double wbg = w * wc;
    blk.BG.topLeftCorner<3, 3>().noalias() +=
        wbg * (beta.dot(gamma) * Mat3::Identity() - gamma * beta.transpose());
    blk.BG.topRightCorner<3, 3>() += wbg * Sb;
    blk.BG.bottomLeftCorner<3, 3>() -= wbg * Sg;
    blk.BG.bottomRightCorner<3, 3>().diagonal().array() += wbg;
    blk.Br.head<3>() += w * beta.cross(r);
    blk.Br.tail<3>() += w * r;
    blk.Gr.head<3>() += wbg * gamma.cross(r);
    blk.Gr.tail<3>() += wbg * r;
    blk.has_blend = true;
  }
}

// Shifts a quadratic in the twist at pivot c to one in the twist at pivot p: with
// X = [I 0; D I], D = -[d]x, d = c - p, returns Q X (needed for the cross terms) and
// writes X' Q X, X' b. Exploits the block structure instead of 6x6 products.
void ShiftQuadratic(const Mat6& Q, const Vec6& b, const Vec3& d, Mat6* QX, Mat6* XtQX, Vec6* Xtb) {
  // Q X: left columns gain Q_right * D = -Q_right [d]x, built column by column from
  // (d x e_k) so the skew structure costs 6 column updates instead of a 6x3x3 product.
  const auto R = Q.rightCols<3>();
  QX->col(0) = Q.col(0) - (d.z() * R.col(1) - d.y() * R.col(2));
  QX->col(1) = Q.col(1) - (d.x() * R.col(2) - d.z() * R.col(0));
  QX->col(2) = Q.col(2) - (d.y() * R.col(0) - d.x() * R.col(1));
  QX->rightCols<3>() = R;
  // X' (Q X): top rows gain D' * bottom = [d]x * bottom, row by row likewise.
  const auto B = QX->bottomRows<3>();
  XtQX->bottomRows<3>() = B;
  XtQX->row(0) = QX->row(0) + (d.y() * B.row(2) - d.z() * B.row(1));
  XtQX->row(1) = QX->row(1) + (d.z() * B.row(0) - d.x() * B.row(2));
  XtQX->row(2) = QX->row(2) + (d.x() * B.row(1) - d.y() * B.row(0));
  Xtb->head<3>() = b.head<3>() + d.cross(b.tail<3>());
  Xtb->tail<3>() = b.tail<3>();
}

// Cholesky factorisation H = L L' of a 3x3 matrix in place (lower triangle), with the
// reciprocals of L's diagonal in inv_diag so the triangular solves below multiply
// instead of divide (a division costs several multiplies' latency, and these run for
// every joint of every iteration). Returns false unless H is positive definite.
bool CholeskyInPlace3(Mat3* H, Vec3* inv_diag) {
  Mat3& A = *H;
  if (!(A(0, 0) > 0.0)) return false;
  const double l00 = std::sqrt(A(0, 0)), i0 = 1.0 / l00;
  const double l10 = A(1, 0) * i0, l20 = A(2, 0) * i0;
  const double d1 = A(1, 1) - l10 * l10;
  if (!(d1 > 0.0)) return false;
  const double l11 = std::sqrt(d1), i1 = 1.0 / l11;
  const double l21 = (A(2, 1) - l20 * l10) * i1;
  const double d2 = A(2, 2) - l20 * l20 - l21 * l21;
  if (!(d2 > 0.0)) return false;
  const double l22 = std::sqrt(d2);
  A << l00, 0.0, 0.0, l10, l11, 0.0, l20, l21, l22;
  *inv_diag = Vec3(i0, i1, 1.0 / l22);
  return true;
}

// Solves L X = M and L y = v in place for lower-triangular L.
void ForwardSubstitute3(const Mat3& L, const Vec3& inv_diag, Eigen::Matrix<double, 3, 6>* M,
                        Vec3* v) {
  M->row(0) *= inv_diag[0];
  M->row(1) = (M->row(1) - L(1, 0) * M->row(0)) * inv_diag[1];
  M->row(2) = (M->row(2) - L(2, 0) * M->row(0) - L(2, 1) * M->row(1)) * inv_diag[2];
  (*v)[0] *= inv_diag[0];
  (*v)[1] = ((*v)[1] - L(1, 0) * (*v)[0]) * inv_diag[1];
  (*v)[2] = ((*v)[2] - L(2, 0) * (*v)[0] - L(2, 1) * (*v)[1]) * inv_diag[2];
}

// Solves L' x = v in place for lower-triangular L.
void BackSubstitute3(const Mat3& L, const Vec3& inv_diag, Vec3* v) {
  (*v)[2] *= inv_diag[2];
  (*v)[1] = ((*v)[1] - L(2, 1) * (*v)[2]) * inv_diag[1];
  (*v)[0] = ((*v)[0] - L(1, 0) * (*v)[1] - L(2, 0) * (*v)[2]) * inv_diag[0];
}

// Writes K = H^-1 HqV and k = H^-1 g for a symmetric positive definite H. Returns false
// if H is not positive definite. Small systems use the closed-form inverse; the 6x6
// (free joint) uses a Cholesky factorisation with vector solves, because Eigen's
// matrix right-hand-side path is a blocked general solver, slow at these sizes.
template <int N>
bool SolveSpd(const Eigen::Matrix<double, N, N>& H, const Eigen::Matrix<double, N, 6>& HqV,
              const Eigen::Matrix<double, N, 1>& g, JointBlock* blk) {
  if constexpr (N <= 3) {
    // Sylvester's criterion: all leading principal minors positive.
    if (!(H(0, 0) > 0.0)) return false;
    if constexpr (N >= 2) {
      if (!(H(0, 0) * H(1, 1) - H(0, 1) * H(1, 0) > 0.0)) return false;
    }
    if (!(H.determinant() > 0.0)) return false;
    const Eigen::Matrix<double, N, N> inverse = H.inverse();
    blk->K.template topRows<N>().noalias() = inverse * HqV;
    blk->k.template head<N>().noalias() = inverse * g;
  } else {
    const Eigen::LLT<Eigen::Matrix<double, N, N>> llt(H);
    if (llt.info() != Eigen::Success) return false;
    for (int c = 0; c < 6; ++c) blk->K.template block<N, 1>(0, c) = llt.solve(HqV.col(c));
    blk->k.template head<N>() = llt.solve(g);
  }
  return true;
}

// The motion subspace at the joint's own pivot, world axes: rotation DOF are (e_i; 0)
// (or (a_W; 0) for a hinge), translation DOF (0; e_i).
template <int N>
Eigen::Matrix<double, 6, N> MotionSubspace(const Joint& joint, const Mat3& R_WJ) {
  Eigen::Matrix<double, 6, N> S = Eigen::Matrix<double, 6, N>::Zero();
  if constexpr (N == 1) {
    S.template block<3, 1>(0, 0) = R_WJ * joint.hinge_axis;
  } else if constexpr (N == 3) {
    S.template topRows<3>().setIdentity();
  } else {
    S.template block<3, 3>(3, 0).setIdentity();  // translation first, as in the DOF layout
    S.template block<3, 3>(0, 3).setIdentity();
  }
  return S;
}

// Eliminates joint blk (N DOF; N = 0 for a fixed joint) into its parent, whose pivot is
// at -d from this joint's; for the root (parent == nullptr) the parent twist is zero.
template <int N, typename PriorH, typename PriorG>
bool EliminateJoint(const Joint& joint, const Mat3& R_WJ, const Vec3& d, JointBlock* blk,
                    double damping, const PriorH& prior_h, const PriorG& prior_g,
                    JointBlock* parent) {
  AddMoments(blk);
  Mat6 QX, XtQX;
  Vec6 Xtb;
  if (parent != nullptr) ShiftQuadratic(blk->Q, blk->b, d, &QX, &XtQX, &Xtb);
  if constexpr (N > 0) {
    const Eigen::Matrix<double, 6, N> S = MotionSubspace<N>(joint, R_WJ);
    Eigen::Matrix<double, N, N> H;
    Eigen::Matrix<double, N, 6> HqV;
    Eigen::Matrix<double, N, 1> g;
    if constexpr (N == 3) {
      // Ball joints dominate; their subspace [I; 0] just selects the rotational rows.
      H = blk->Q.template topLeftCorner<3, 3>();
      g = blk->b.template head<3>();
      if (blk->has_blend) {
        H += blk->GG.template topLeftCorner<3, 3>();
        g += blk->Gr.template head<3>();
      }
      if (parent != nullptr) {
        HqV = QX.template topRows<3>();
        if (blk->has_blend) HqV += blk->BG.template leftCols<3>().transpose();
      } else {
        HqV.setZero();
      }
    } else {
      if (blk->has_blend) {
        H.noalias() = S.transpose() * (blk->Q + blk->GG) * S;
        g.noalias() = S.transpose() * (blk->b + blk->Gr);
      } else {
        H.noalias() = S.transpose() * blk->Q * S;
        g.noalias() = S.transpose() * blk->b;
      }
      if (parent != nullptr) {
        HqV.noalias() = S.transpose() * QX;
        if (blk->has_blend) HqV.noalias() += S.transpose() * blk->BG.transpose();
      } else {
        HqV.setZero();
      }
    }
    g += prior_g;
    for (int i = 0; i < N; ++i) H(i, i) += damping * H(i, i) + prior_h[i] + 1e-12;
    blk->dofs = N;
    if constexpr (N != 3)
      blk->S.template leftCols<N>() = S;  // ball joints: S = [I; 0], used implicitly
    if constexpr (N == 3) {
      // Symmetric form: with H = L L', W = L^-1 HqV and w = L^-1 g, the parent receives
      // -W'W and -W'w, and the forward sweep solves L' dq = w - W V_p. About half the
      // work of forming K = H^-1 HqV, on the joints that dominate the cost.
      if (!CholeskyInPlace3(&H, &blk->L_inv_diag)) return false;
      blk->L = H;
      ForwardSubstitute3(H, blk->L_inv_diag, &HqV, &g);
      blk->K.template topRows<3>() = HqV;
      blk->k.template head<3>() = g;
      if (parent != nullptr) {
        // -W'W as three rank-one updates: Eigen's 6x3x6 lazy product is slower here.
        XtQX.noalias() -= HqV.row(0).transpose() * HqV.row(0);
        XtQX.noalias() -= HqV.row(1).transpose() * HqV.row(1);
        XtQX.noalias() -= HqV.row(2).transpose() * HqV.row(2);
        parent->Q += XtQX;
        parent->b += Xtb;
        parent->b.noalias() -= HqV.transpose() * g;
      }
    } else {
      if (!SolveSpd<N>(H, HqV, g, blk)) return false;
      if (parent != nullptr) {
        parent->Q += XtQX;
        parent->Q.noalias() -= HqV.transpose() * blk->K.template topRows<N>();
        parent->b += Xtb;
        parent->b.noalias() -= HqV.transpose() * blk->k.template head<N>();
      }
    }
  } else {
    blk->dofs = 0;
    if (parent != nullptr) {
      parent->Q += XtQX;
      parent->b += Xtb;
    }
  }
  if (parent != nullptr && blk->has_blend) {
    parent->Q += blk->BB;
    parent->b += blk->Br;
  }
  return true;
}

// Solves the damped system for the step dq (world axes at each pivot; free-joint
// translations in world axes). prior_h/prior_g (size num_dofs) hold the priors' Hessian
// diagonal and negative gradient. Returns false on a numerical failure.
bool ComputeStep(const Skeleton& skeleton, double damping, const Eigen::VectorXd& prior_h,
                 const Eigen::VectorXd& prior_g, const KinematicsWorkspace& ws,
                 std::vector<JointBlock>* blocks, Eigen::VectorXd* dq) {
  const int n = skeleton.num_joints();
  for (int j = n - 1; j >= 0; --j) {
    const Joint& joint = skeleton.joint(j);
    const auto uj = static_cast<size_t>(j);
    JointBlock& blk = (*blocks)[uj];
    const int p = joint.parent.value;
    JointBlock* parent = p >= 0 ? &(*blocks)[static_cast<size_t>(p)] : nullptr;
    const Vec3 d = p >= 0 ? Vec3(ws.p_WJ[uj] - ws.p_WJ[static_cast<size_t>(p)]) : Vec3::Zero();
    const int k = skeleton.dof_offset(j);
    bool ok = true;
    switch (joint.type) {
      case JointType::kFixed:
        ok = EliminateJoint<0>(joint, ws.R_WJ[uj], d, &blk, damping, prior_h.segment<0>(k),
                               prior_g.segment<0>(k), parent);
        break;
      case JointType::kHinge:
        ok = EliminateJoint<1>(joint, ws.R_WJ[uj], d, &blk, damping, prior_h.segment<1>(k),
                               prior_g.segment<1>(k), parent);
        break;
      case JointType::kBall:
        ok = EliminateJoint<3>(joint, ws.R_WJ[uj], d, &blk, damping, prior_h.segment<3>(k),
                               prior_g.segment<3>(k), parent);
        break;
      case JointType::kFree:
        ok = EliminateJoint<6>(joint, ws.R_WJ[uj], d, &blk, damping, prior_h.segment<6>(k),
                               prior_g.segment<6>(k), parent);
        break;
    }
    if (!ok) return false;
  }
  for (int j = 0; j < n; ++j) {
    const auto uj = static_cast<size_t>(j);
    JointBlock& blk = (*blocks)[uj];
    const int p = skeleton.joint(j).parent.value;
    const int k = skeleton.dof_offset(j);
    if (p < 0) {
      blk.V.setZero();
      if (skeleton.joint(j).type == JointType::kBall) {
        Vec3 x = blk.k.head<3>();
        BackSubstitute3(blk.L, blk.L_inv_diag, &x);
        dq->segment<3>(k) = x;
      } else {
        for (int c = 0; c < blk.dofs; ++c) (*dq)[k + c] = blk.k[c];
      }
    } else {
      // K acts on the parent's twist at the parent's pivot; this joint's twist is that
      // twist seen at this pivot (same w, v + w x d) plus its own DOF.
      const Vec6& Vp = (*blocks)[static_cast<size_t>(p)].V;
      const Vec3 d = ws.p_WJ[uj] - ws.p_WJ[static_cast<size_t>(p)];
      blk.V.head<3>() = Vp.head<3>();
      blk.V.tail<3>() = Vp.tail<3>() + Vp.head<3>().cross(d);
      if (skeleton.joint(j).type == JointType::kBall) {
        Vec3 x = blk.k.head<3>() - blk.K.topRows<3>() * Vp;
        BackSubstitute3(blk.L, blk.L_inv_diag, &x);
        dq->segment<3>(k) = x;
      } else {
        for (int c = 0; c < blk.dofs; ++c) (*dq)[k + c] = blk.k[c] - blk.K.row(c).dot(Vp);
      }
    }
    if (skeleton.joint(j).type == JointType::kBall) {
      blk.V.head<3>() += dq->segment<3>(k);
    } else {
      for (int c = 0; c < blk.dofs; ++c) blk.V += blk.S.col(c) * (*dq)[k + c];
    }
  }
  return dq->allFinite();
}

// Converts a world-axis step to the local-axis step IntegratePose takes.
void WorldStepToLocal(const Skeleton& skeleton, const KinematicsWorkspace& ws,
                      Eigen::VectorXd* dq) {
  for (int j = 0; j < skeleton.num_joints(); ++j) {
    const Joint& joint = skeleton.joint(j);
    const auto uj = static_cast<size_t>(j);
    const int k = skeleton.dof_offset(j);
    if (joint.type == JointType::kBall)
      dq->segment<3>(k) = ws.R_WJ[uj].transpose() * dq->segment<3>(k);
    if (joint.type == JointType::kFree) {
      const int p = joint.parent.value;
      if (p >= 0)
        dq->segment<3>(k) = ws.R_WJ[static_cast<size_t>(p)].transpose() * dq->segment<3>(k);
      dq->segment<3>(k + 3) = ws.R_WJ[uj].transpose() * dq->segment<3>(k + 3);
    }
  }
}

// Expresses a local-axis tangent vector (as PoseDifference writes it) in world axes.
void LocalTangentToWorld(const Skeleton& skeleton, const KinematicsWorkspace& ws,
                         Eigen::VectorXd* v) {
  for (int j = 0; j < skeleton.num_joints(); ++j) {
    const JointType type = skeleton.joint(j).type;
    const auto uj = static_cast<size_t>(j);
    const int k = skeleton.dof_offset(j);
    if (type == JointType::kBall) v->segment<3>(k) = ws.R_WJ[uj] * v->segment<3>(k);
    if (type == JointType::kFree) v->segment<3>(k + 3) = ws.R_WJ[uj] * v->segment<3>(k + 3);
  }
}

void ClearBlocks(std::vector<JointBlock>* blocks) {
  for (JointBlock& blk : *blocks) {
    blk.Q.setZero();
    blk.b.setZero();
    blk.m0 = 0.0;
    blk.m1.setZero();
    blk.M2.setZero();
    blk.xr.setZero();
    blk.wr.setZero();
    if (blk.has_blend) {
      blk.BB.setZero();
      blk.BG.setZero();
      blk.GG.setZero();
      blk.Br.setZero();
      blk.Gr.setZero();
      blk.has_blend = false;
    }
  }
}

// Constant-velocity extrapolation, scaled by gain: X_pred = X_cur * (X_prev^-1 X_cur)^gain.
void PredictConstantVelocity(const Skeleton& skeleton, const Pose& previous, const Pose& current,
                             double gain, Pose* predicted) {
  for (int j = 0; j < skeleton.num_joints(); ++j) {
    const auto uj = static_cast<size_t>(j);
    const Quat delta = previous.rotation[uj].conjugate() * current.rotation[uj];
    const Quat step = gain == 1.0 ? delta : ExpRotation(gain * LogRotation(delta));
    predicted->rotation[uj] = (current.rotation[uj] * step).normalized();
    predicted->translation[uj] =
        current.translation[uj] + gain * (current.translation[uj] - previous.translation[uj]);
  }
}

// Cold start: rigidly aligns the rest-pose markers with the observation (Kabsch) and
// moves the first free joint accordingly, so LM starts facing the right way.
void AlignRestPose(const Skeleton& skeleton, const MarkerSet& markers,
                   std::span<const Vec3> observed, std::span<const double> weights,
                   int first_free_joint, std::span<const Vec3> rest_markers, const Pose& rest,
                   Pose* pose, KinematicsWorkspace* ws) {
  *pose = rest;
  if (first_free_joint < 0) return;
  Vec3 model_mean = Vec3::Zero(), data_mean = Vec3::Zero();
  double total = 0.0;
  for (int m = 0; m < markers.num_markers(); ++m) {
    const auto um = static_cast<size_t>(m);
    if (!UsableMarker(observed[um], weights[um])) continue;
    model_mean += weights[um] * rest_markers[um];
    data_mean += weights[um] * observed[um];
    total += weights[um];
  }
  if (total <= 0.0) return;
  model_mean /= total;
  data_mean /= total;
  Mat3 cov = Mat3::Zero();
  for (int m = 0; m < markers.num_markers(); ++m) {
    const auto um = static_cast<size_t>(m);
    if (!UsableMarker(observed[um], weights[um])) continue;
    cov.noalias() +=
        weights[um] * (observed[um] - data_mean) * (rest_markers[um] - model_mean).transpose();
  }
  const Eigen::JacobiSVD<Mat3> svd(cov, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Mat3 D = Mat3::Identity();
  if ((svd.matrixU() * svd.matrixV().transpose()).determinant() < 0.0) D(2, 2) = -1.0;
  const Mat3 R = svd.matrixU() * D * svd.matrixV().transpose();
  const Vec3 t = data_mean - R * model_mean;

  ForwardKinematics(skeleton, rest, ws);
  const auto f = static_cast<size_t>(first_free_joint);
  const Mat3 R_WF = R * ws->R_WJ[f];
  const Vec3 p_WF = R * ws->p_WJ[f] + t;
  const int parent = skeleton.joint(first_free_joint).parent.value;
  const Mat3 R_WP = parent < 0 ? Mat3::Identity() : ws->R_WJ[static_cast<size_t>(parent)];
  const Vec3 p_WP = parent < 0 ? Vec3::Zero() : ws->p_WJ[static_cast<size_t>(parent)];
  pose->rotation[f] = Quat(R_WP.transpose() * R_WF).normalized();
  pose->translation[f] = R_WP.transpose() * (p_WF - p_WP);
}

}  // namespace

void IkOptions::Validate() const {
  auto require = [](bool ok, const char* field, const char* expected) {
    if (!ok)
      throw std::invalid_argument(std::string("IkOptions.") + field + ": expected " + expected);
  };
  require(max_iterations >= 1, "max_iterations", ">= 1");
  require(cold_start_max_iterations >= 1, "cold_start_max_iterations", ">= 1");
  require(initial_damping >= 0.0 && std::isfinite(initial_damping), "initial_damping",
          "a finite value >= 0");
  require(function_tolerance >= 0.0, "function_tolerance", ">= 0");
  require(step_tolerance >= 0.0, "step_tolerance", ">= 0");
  require(residual_tolerance_m >= 0.0, "residual_tolerance_m", ">= 0");
  require(huber_delta_m >= 0.0 && std::isfinite(huber_delta_m), "huber_delta_m",
          "a finite value >= 0");
  require(cold_start_min_fraction >= 0.0 && cold_start_min_fraction <= 1.0,
          "cold_start_min_fraction", "0..1");
  require(temporal_weight >= 0.0 && std::isfinite(temporal_weight), "temporal_weight",
          "a finite value >= 0");
  require(rest_weight >= 0.0 && std::isfinite(rest_weight), "rest_weight", "a finite value >= 0");
  require(min_markers >= 1, "min_markers", ">= 1");
  require(prediction_velocity_gain >= 0.0 && prediction_velocity_gain <= 1.0,
          "prediction_velocity_gain", "0..1");
  require(unseen_knee_tolerance_rad >= 0.0 && unseen_knee_tolerance_rad <= M_PI,
          "unseen_knee_tolerance_rad", "0..pi");
  require(unseen_knee_max_turn_rad >= 0.0 && std::isfinite(unseen_knee_max_turn_rad),
          "unseen_knee_max_turn_rad", "a finite value >= 0");
}

const char* to_string(IkStatus status) {
  switch (status) {
    case IkStatus::kConverged: return "converged";
    case IkStatus::kMaxIterations: return "max_iterations";
    case IkStatus::kTooFewMarkers: return "too_few_markers";
    case IkStatus::kNumericalFailure: return "numerical_failure";
  }
  return "?";
}

IkState::IkState(const Skeleton& skeleton, const MarkerSet& markers)
    : pose_(RestPose(skeleton)),
      previous_(pose_),
      trial_(pose_),
      rest_(pose_),
      cold_best_(pose_),
      ws_(skeleton),
      trial_ws_(skeleton),
      predicted_(static_cast<size_t>(markers.num_markers()), Vec3::Zero()),
      trial_predicted_(predicted_),
      rest_markers_(predicted_),
      blocks_(static_cast<size_t>(skeleton.num_joints())),
      dq_(Eigen::VectorXd::Zero(skeleton.num_dofs())),
      step_total_(dq_),
      trial_total_(dq_),
      rest_error_(dq_),
      prior_mask_(dq_),
      prior_h_(dq_),
      prior_g_(dq_),
      local_step_(dq_),
      knee_swivel_(skeleton, markers) {
  // Priors act on rotations only: translations are always well observed.
  for (int j = 0; j < skeleton.num_joints(); ++j) {
    const int k = skeleton.dof_offset(j);
    const JointType type = skeleton.joint(j).type;
    if (type == JointType::kHinge) prior_mask_[k] = 1.0;
    if (type == JointType::kBall) prior_mask_.segment<3>(k).setOnes();
    if (type == JointType::kFree) prior_mask_.segment<3>(k + 3).setOnes();
  }
  for (JointBlock& blk : blocks_) {
    blk.Q.setZero();
    blk.BB.setZero();
    blk.BG.setZero();
    blk.GG.setZero();
    blk.S.setZero();
    blk.K.setZero();
    blk.b.setZero();
    blk.Br.setZero();
    blk.Gr.setZero();
    blk.k.setZero();
    blk.V.setZero();
  }
  ForwardKinematics(skeleton, rest_, &ws_);
  EvaluateMarkers(markers, ws_, rest_markers_);
  predicted_ = rest_markers_;
  for (int j = 0; j < skeleton.num_joints(); ++j) {
    if (skeleton.joint(j).type == JointType::kFree) {
      first_free_joint_ = j;
      break;
    }
  }
}

void IkState::Reset() { history_ = 0; }

void IkState::Reset(const Pose& pose) {
  pose_ = pose;
  history_ = 1;
}

bool ComputeIkStep(const Skeleton& skeleton, const MarkerSet& markers, const IkOptions& options,
                   std::span<const Vec3> observed, std::span<const double> weights,
                   const Pose& pose, double damping, IkState* state, Eigen::VectorXd* dq) {
  IkState& s = *state;
  ForwardKinematics(skeleton, pose, &s.ws_);
  EvaluateMarkers(markers, s.ws_, s.predicted_);
  PoseDifference(skeleton, s.rest_, pose, s.rest_error_);
  s.rest_error_.array() *= s.prior_mask_.array();
  LocalTangentToWorld(skeleton, s.ws_, &s.rest_error_);
  s.prior_h_ = (options.temporal_weight + options.rest_weight) * s.prior_mask_;
  s.prior_g_ = -options.rest_weight * s.rest_error_;
  ClearBlocks(&s.blocks_);
  AccumulateMarkers(markers, options, observed, weights, s.predicted_, s.ws_, &s.blocks_);
  dq->resize(skeleton.num_dofs());
  if (!ComputeStep(skeleton, damping, s.prior_h_, s.prior_g_, s.ws_, &s.blocks_, dq)) return false;
  WorldStepToLocal(skeleton, s.ws_, dq);
  return true;
}

IkSummary SolveIk(const Skeleton& skeleton, const MarkerSet& markers, const IkOptions& options,
                  std::span<const Vec3> observed, std::span<const double> weights, IkState* state) {
  IkState& s = *state;
  IkSummary summary;
  for (int m = 0; m < markers.num_markers(); ++m)
    if (UsableMarker(observed[static_cast<size_t>(m)], weights[static_cast<size_t>(m)]))
      ++summary.markers_used;
  if (summary.markers_used < options.min_markers ||
      (s.history_ == 0 &&
       summary.markers_used < options.cold_start_min_fraction * markers.num_markers())) {
    // Hold the last solution; the velocity history is no longer trustworthy.
    summary.status = IkStatus::kTooFewMarkers;
    s.history_ = std::min(s.history_, 1);
    return summary;
  }

  // Warm start (constant-velocity prediction when two solutions are known) or cold start.
  int max_iterations = options.max_iterations;
  if (s.history_ >= 2 && options.predict_constant_velocity) {
    PredictConstantVelocity(skeleton, s.previous_, s.pose_, options.prediction_velocity_gain,
                            &s.trial_);
    std::swap(s.previous_, s.pose_);
    std::swap(s.pose_, s.trial_);
  } else if (s.history_ >= 1) {
    s.previous_ = s.pose_;
  } else {
    summary.cold_start = true;
    max_iterations = options.cold_start_max_iterations;
    AlignRestPose(skeleton, markers, observed, weights, s.first_free_joint_, s.rest_markers_,
                  s.rest_, &s.pose_, &s.ws_);
    s.previous_ = s.pose_;
  }

  // Priors in the tangent space of the start pose (see PriorCost), in the world axes the
  // steps are taken about.
  auto begin_at_start = [&]() {
    ForwardKinematics(skeleton, s.pose_, &s.ws_);
    PoseDifference(skeleton, s.rest_, s.pose_, s.rest_error_);
    s.rest_error_.array() *= s.prior_mask_.array();
    LocalTangentToWorld(skeleton, s.ws_, &s.rest_error_);
    s.step_total_.setZero();
  };
  begin_at_start();
  // The warm start of a cold solve is only the aligned rest pose: nothing to stay near.
  const double at = summary.cold_start ? 0.0 : options.temporal_weight, ar = options.rest_weight;
  s.prior_h_ = (at + ar) * s.prior_mask_;
  auto cost_under = [&](const IkOptions& loss) {
    return MarkerCost(markers, loss, observed, weights, s.ws_, s.predicted_) +
           PriorCost(at, ar, s.prior_mask_, s.rest_error_, s.step_total_);
  };

  double cost = cost_under(options);
  summary.initial_cost = cost;
  // A cold start is far from the answer: the warm-start tolerance would stop it early,
  // in the basin of whatever local minimum it is crossing.
  const double function_tolerance =
      summary.cold_start ? std::min(options.function_tolerance, 1e-10) : options.function_tolerance;
  double weight_sum = 0.0;
  for (int m = 0; m < markers.num_markers(); ++m)
    if (UsableMarker(observed[static_cast<size_t>(m)], weights[static_cast<size_t>(m)]))
      weight_sum += weights[static_cast<size_t>(m)];
  const double cost_floor = summary.cold_start ? 0.0
                                               : 0.5 * weight_sum * options.residual_tolerance_m *
                                                     options.residual_tolerance_m;
  // Levenberg-Marquardt from the current pose under `loss`, at most max_iterations steps;
  // `cost` must hold the current pose's cost under that loss.
  IkOptions loss = options;
  auto descend = [&]() {
    double damping = options.initial_damping;
    summary.status = IkStatus::kMaxIterations;
    for (int iteration = 0; iteration < max_iterations; ++iteration) {
      ++summary.iterations;
      // Elimination adds children into their parents' blocks in place, so every attempt,
      // including a retry after a rejected step, starts from freshly accumulated blocks.
      ClearBlocks(&s.blocks_);
      AccumulateMarkers(markers, loss, observed, weights, s.predicted_, s.ws_, &s.blocks_);
      s.prior_g_ =
          -(at * s.step_total_ + ar * (s.rest_error_ + s.step_total_)).cwiseProduct(s.prior_mask_);
      if (!ComputeStep(skeleton, damping, s.prior_h_, s.prior_g_, s.ws_, &s.blocks_, &s.dq_)) {
        summary.status = IkStatus::kNumericalFailure;
        return;
      }
      s.trial_ = s.pose_;
      s.local_step_ = s.dq_;
      WorldStepToLocal(skeleton, s.ws_, &s.local_step_);
      IntegratePose(skeleton, s.local_step_, &s.trial_);
      if (options.apply_joint_limits) ApplyJointLimits(skeleton, &s.trial_);
      ForwardKinematics(skeleton, s.trial_, &s.trial_ws_);
      s.trial_total_ = s.step_total_ + s.dq_;
      const double trial_cost =
          MarkerCost(markers, loss, observed, weights, s.trial_ws_, s.trial_predicted_) +
          PriorCost(at, ar, s.prior_mask_, s.rest_error_, s.trial_total_);
      const double step_size = s.dq_.cwiseAbs().maxCoeff();
      if (std::isfinite(trial_cost) && trial_cost <= cost) {
        std::swap(s.pose_, s.trial_);
        std::swap(s.ws_, s.trial_ws_);
        std::swap(s.predicted_, s.trial_predicted_);
        std::swap(s.step_total_, s.trial_total_);
        const double decrease = cost - trial_cost;
        cost = trial_cost;
        damping = std::max(damping * 0.3, 1e-9);
        if (decrease <= function_tolerance * (cost + decrease) ||
            step_size <= options.step_tolerance || cost <= cost_floor) {
          summary.status = IkStatus::kConverged;
          return;
        }
      } else {
        damping = std::max(damping * 10.0, 1e-6);
        if (damping > 1e8 || step_size <= options.step_tolerance) {
          // No descent direction left: the current pose is a minimum to working precision.
          summary.status = IkStatus::kConverged;
          return;
        }
      }
    }
  };
  descend();
  // A cold start begins at the aligned rest pose, maybe far from the answer, where a robust
  // loss can take the clean markers of a badly started limb for outliers and settle in a
  // minimum that ignores them (a Bandai clavicle and upper arm 5-11 cm off three clean
  // markers, which the detectors then rejected for 1.4 s). Least squares brings every limb
  // to its markers, and the robust loss refines from there; but least squares also
  // follows whatever is wrong in the data (CMU 01_01's gap fill, started that way alone:
  // 17.2 -> 22.6 mm). So both are tried, and the lower robust cost is kept.
  if (summary.cold_start && options.huber_delta_m > 0.0 && options.cold_start_least_squares_first &&
      summary.status != IkStatus::kNumericalFailure && std::isfinite(cost)) {
    const double robust_only = cost;
    const IkStatus robust_only_status = summary.status;
    s.cold_best_ = s.pose_;
    s.pose_ = s.previous_;  // the aligned rest pose again
    begin_at_start();
    loss.huber_delta_m = 0.0;
    cost = cost_under(loss);
    descend();
    loss.huber_delta_m = options.huber_delta_m;
    cost = cost_under(loss);
    if (summary.status != IkStatus::kNumericalFailure) descend();
    if (summary.status == IkStatus::kNumericalFailure || !std::isfinite(cost) ||
        cost >= robust_only) {
      s.pose_ = s.cold_best_;
      ForwardKinematics(skeleton, s.pose_, &s.ws_);
      EvaluateMarkers(markers, s.ws_, s.predicted_);
      cost = robust_only;
      summary.status = robust_only_status;
    }
  }
  if (summary.status == IkStatus::kNumericalFailure || !std::isfinite(cost)) {
    summary.status = IkStatus::kNumericalFailure;
    s.pose_ = s.previous_;
    ForwardKinematics(skeleton, s.pose_, &s.ws_);
    EvaluateMarkers(markers, s.ws_, s.predicted_);
    s.history_ = 0;
    return summary;
  }
  // Only a solve that turns knees needs to learn their axes (the final solve; not the
  // references, the anchor or calibration's tracking).
  // An unseen knee beyond the tolerance is turned back toward it at a limited rate, so
  // as not to pop. On the very first solve nothing was published yet to pop from, and the
  // knee is where the rest pose's straight leg happened to bend, no evidence to keep: it
  // is turned onto the axis the foot asks for, all the way (a Bandai run's first frame:
  // 29.5 -> 2.5 cm). A later cold start (after a re-sync) follows the warm rule.
  const bool first_ever = summary.cold_start && !s.ever_solved_;
  constexpr double kOntoTheAxisRad = 1e-6;
  if (options.unseen_knee_tolerance_rad > 0.0)
    summary.knees_turned = s.knee_swivel_.Update(
        skeleton, observed, weights,
        first_ever ? kOntoTheAxisRad : options.unseen_knee_tolerance_rad,
        first_ever ? 0.0 : options.unseen_knee_max_turn_rad, &s.pose_, &s.ws_, &s.previous_);
  if (summary.knees_turned > 0) EvaluateMarkers(markers, s.ws_, s.predicted_);
  summary.final_cost = cost;
  double sum_sq = 0.0;
  for (int m = 0; m < markers.num_markers(); ++m) {
    const auto um = static_cast<size_t>(m);
    if (UsableMarker(observed[um], weights[um]))
      sum_sq += (observed[um] - s.predicted_[um]).squaredNorm();
  }
  summary.rms_residual_m = std::sqrt(sum_sq / summary.markers_used);
  s.history_ = std::min(s.history_ + 1, 2);
  s.ever_solved_ = true;
  return summary;
}

}  // namespace mocapd
