// Hermite repair of masked samples onto the reference path (see the header).
#include "filters/gap_repair.hpp"

#include <algorithm>

#include "filters/hermite.hpp"

namespace mocapd {
GapRepair::GapRepair(int markers, const CleanupOptions& options)
    : options_(options), rules_(FrameRules(options)), tracks_(static_cast<size_t>(markers)) {}

void GapRepair::Reset() { std::fill(tracks_.begin(), tracks_.end(), Track{}); }

void GapRepair::Repair(const CleanupWindow& window, int64_t tau, int64_t newest, CleanFrame* out,
                       CleanupCounters* counters) {
  const WindowFrame& s = window.at(tau);
  const double max_v = rules_.max_offset_velocity_m;
  const double dt = 1.0 / options_.rate_hz;
  const double max_reference_step_change = options_.fill_reference_acceleration_mps2 * dt * dt;
  const bool has_reference_before = window.Holds(tau - 1);
  // The part of X^'s path over frames from..to that is snapping rather than moving (its
  // per-frame change beyond the acceleration limit), summed; `velocity` comes in as the
  // snap-free reference velocity at from - 1 and leaves as the one at `to`.
  auto reference_snap = [&](size_t m, int64_t from, int64_t to, Vec3* velocity) {
    Vec3 snap = Vec3::Zero();
    if (max_reference_step_change <= 0.0 || !has_reference_before) return snap;
    for (int64_t g = from; g <= to; ++g) {
      // From a reference that was no solve (the rest pose, before the subject was first
      // solved) there is no step: held as a snap, it put a fill's first frames back where
      // the rest pose stood, 1.6 m from the body (a take with an empty first frame).
      if (!window.at(g - 1).reference_solved) {
        *velocity = Vec3::Zero();
        continue;
      }
      const Vec3 step = window.at(g).reference[m] - window.at(g - 1).reference[m];
      const Vec3 change = step - *velocity;
      const Vec3 excess = change - ClampNorm(change, max_reference_step_change);
      snap += excess;
      *velocity = step - excess;
    }
    return snap;
  };
  for (size_t m = 0; m < tracks_.size(); ++m) {
    Track& track = tracks_[m];
    const Vec3& ref = s.reference[m];
    Vec3 x = Vec3::Constant(kNaN);
    MarkerStatus status = MarkerStatus::kRepaired;
    MaskReason reason = s.mask[m];
    bool interpolated = false;  // filled between two known ends
    // Each branch leaves x and the track's offset / velocities for the next frame.
    if (reason == MaskReason::kNone) {
      // Observed (or relabelled): published exactly as it is.
      x = s.raw[m];
      if (s.relabelled[m]) reason = MaskReason::kSwap;
      status = s.relabelled[m] ? MarkerStatus::kRepaired : MarkerStatus::kObserved;
      const Vec3 offset = x - ref;
      // Smoothed over consecutive captured samples: a fill starts from this velocity, and
      // one frame's change is mostly the capture's noise.
      const Vec3 step = offset - track.offset;
      const double w = rules_.fill_start_velocity_weight;
      track.offset_velocity = !track.has_published ? Vec3::Zero()
                              : track.last_observed == tau - 1
                                  ? Vec3(w * step + (1.0 - w) * track.offset_velocity)
                                  : step;
      track.offset = offset;
      track.output_velocity = track.has_published ? Vec3(x - track.output) : Vec3::Zero();
      track.reference_velocity =
          has_reference_before ? Vec3(ref - window.at(tau - 1).reference[m]) : Vec3::Zero();
      track.held_snap.setZero();
      track.last_observed = tau;
    } else {
      // The returning track, if the lookahead shows it within the horizon: further off,
      // the reference carries the fill better than a path to the return would. A marker
      // not published yet has no path to bend, only the return's offset to ride the
      // reference at, so it looks as far as the lookahead shows. The horizon does not
      // count a run of frames with no sample at all past its first: across it the
      // reference knows nothing of the body's motion, and the path to the return is all
      // there is (a walk unseen for 0.83 s, replayed at K = 200, froze, then crossed to
      // the return in the horizon's 0.1 s: the hips 18 cm beyond the truth's step). A
      // lone such frame (a gated glitch, frames lost one at a time between received ones)
      // counts as any other: the reference moves on either side of it.
      int64_t end = -1;
      int64_t frames_passed = 0;
      for (int64_t f = tau + 1; f <= newest; ++f) {
        if (track.has_published && frames_passed >= rules_.fill_interpolation_horizon_frames) break;
        // A re-synchronisation is another world frame, not the marker's return: a fill
        // toward it glided the whole body across the jump through the glitch's frames.
        if (window.at(f).resync) break;
        if (window.at(f).mask[m] == MaskReason::kNone) {
          end = f;
          break;
        }
        if (!window.at(f).blind || !window.at(f - 1).blind) ++frames_passed;
      }
      const bool end_slope_known =
          end >= 0 && end + 1 <= newest && window.at(end + 1).mask[m] == MaskReason::kNone;
      if (!track.has_published) {
        if (end < 0) {
          status = MarkerStatus::kUnrecoverable;  // never seen: nothing to repair from
        } else {
          // Nothing before the gap: ride the reference at the returning track's offset,
          // moving with it (its velocity from the frame before, or on a take's first frame
          // the frame after), so the next frame takes none of its motion for a snap.
          track.offset = window.at(end).raw[m] - window.at(end).reference[m];
          track.offset_velocity = Vec3::Zero();
          track.output_velocity = Vec3::Zero();
          if (s.reference_solved) {
            x = ref + track.offset;
            track.reference_velocity = has_reference_before
                                           ? Vec3(ref - window.at(tau - 1).reference[m])
                                           : Vec3(window.at(tau + 1).reference[m] - ref);
          } else {
            // No reference yet (a take or re-synchronisation that starts with too few
            // markers): the reference here is the template's rest pose, wherever it
            // stands, and riding it put the first frames' markers 1.5 m from the body
            // (a CMU capture with an empty first frame). The first sample seen is nearer.
            x = window.at(end).raw[m];
            track.reference_velocity = Vec3::Zero();
          }
        }
      } else if (end >= 0 && track.last_observed == tau - 1 &&
                 end - tau <= rules_.small_gap_frames) {
        interpolated = true;
        // A short gap right after an observed sample: a plain Hermite on the raw path.
        const HermiteSegment h{track.output, track.output_velocity, window.at(end).raw[m],
                               end_slope_known
                                   ? Vec3(window.at(end + 1).raw[m] - window.at(end).raw[m])
                                   : track.output_velocity,
                               static_cast<double>(end - tau + 1)};
        x = h.Value(1.0);
        track.output_velocity = h.Derivative(1.0);
        const Vec3 offset = x - ref;
        track.offset_velocity = offset - track.offset;
        track.offset = offset;
      } else if (!s.reference_solved) {
        // No reference to ride (see above): the last sample published stays where it is.
        x = track.output;
        track.offset_velocity = Vec3::Zero();
        track.reference_velocity = Vec3::Zero();
        track.output_velocity = Vec3::Zero();
      } else {
        // Offset onto the reference path, from the last published offset and velocity
        // to the returning track's (two-sided), or easing to a constant (one-sided).
        // Both ends are taken against X^ with its snaps taken out, so a reference that
        // jumps (this segment's other markers re-entering its solve) moves no fill.
        HermiteSegment h;
        h.p0 = track.offset;
        h.m0 = ClampNorm(track.offset_velocity, max_v);
        Vec3 velocity = track.reference_velocity;
        const Vec3 snap_now = reference_snap(m, tau, tau, &velocity);
        const Vec3 reference_velocity_now = velocity;
        if (end >= 0) {
          interpolated = true;
          const WindowFrame& e = window.at(end);
          const Vec3 snap_at_end = snap_now + reference_snap(m, tau + 1, end, &velocity);
          h.p1 = e.raw[m] - (e.reference[m] - snap_at_end);
          // The returning track's offset velocity over as many captured frames as the
          // lookahead shows, up to fill_end_velocity_frames.
          int span = 0;
          while (span < rules_.fill_end_velocity_frames && end + span + 1 <= newest &&
                 window.at(end + span + 1).mask[m] == MaskReason::kNone)
            ++span;
          const WindowFrame& later = window.at(end + span);
          h.m1 =
              span > 0
                  ? ClampNorm(((later.raw[m] - later.reference[m]) - (e.raw[m] - e.reference[m])) /
                                  static_cast<double>(span),
                              max_v)
                  : Vec3::Zero();
          h.length = static_cast<double>(end - tau + 1);
        } else {
          h.p1 = h.p0;
          h.m1 = Vec3::Zero();
          h.length = rules_.fill_ease_frames + 1.0;
        }
        x = ref - snap_now + h.Value(1.0);
        if (end < 0) {
          // A held snap is taken up a little each frame: a reference that kept up a real
          // fast motion is followed again, with no jump.
          track.held_snap += snap_now;
          const Vec3 released = rules_.fill_snap_release * track.held_snap;
          track.held_snap -= released;
          x += released;
        } else {
          track.held_snap.setZero();
        }
        track.offset = x - ref;
        track.offset_velocity = h.Derivative(1.0);
        track.reference_velocity = reference_velocity_now;
        track.output_velocity = x - track.output;
      }
    }
    if (status != MarkerStatus::kUnrecoverable) {
      track.output = x;
      track.has_published = true;
    }
    out->markers[m] = x;
    out->status[m] = status;
    out->reason[m] = status == MarkerStatus::kObserved ? MaskReason::kNone : reason;
    out->source[m] = s.mask[m] == MaskReason::kNone           ? SampleSource::kCaptured
                     : status == MarkerStatus::kUnrecoverable ? SampleSource::kNone
                     : interpolated                           ? SampleSource::kInterpolated
                                                              : SampleSource::kExtrapolated;
    ++counters->samples_out;
    if (status == MarkerStatus::kRepaired) ++counters->repaired_by[static_cast<size_t>(reason)];
    if (status == MarkerStatus::kUnrecoverable) ++counters->unrecoverable;
  }
}

}  // namespace mocapd
