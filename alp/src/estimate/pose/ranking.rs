//! Ranking orientation starts by colour: each start's re-render under a
//! coarse, smooth map is compared with the photo by the mean RGB angle,
//! which says whether the probe's colour pattern (a label) is in place,
//! whatever lighting detail a coarse map leaves unexplained. Ties go by the
//! relative error; a probe of one colour goes by its outline.

use glam::Vec3;
use render::pose::Pose;

use crate::estimate::report::StartReport;
use crate::estimate::settings::OrientationSettings;

/// Whether start `a` ranks above start `b`: the smaller colour error, or
/// on a tie the smaller relative error.
pub(in crate::estimate) fn ranks_above(a: &StartReport, b: &StartReport, o: &OrientationSettings) -> bool {
    if (a.rgb_angle_deg - b.rgb_angle_deg).abs() > o.rank_tie_deg {
        a.rgb_angle_deg < b.rgb_angle_deg
    } else {
        a.relative_error < b.relative_error
    }
}

/// Whether two starts rendered alike: colours that tie (between two turns of
/// a probe of one colour only its facets move the angle, by a small fraction
/// of itself) and relative errors the same to `OrientationSettings::same_render`.
pub(in crate::estimate) fn renders_alike(a: &StartReport, b: &StartReport, o: &OrientationSettings) -> bool {
    (a.rgb_angle_deg - b.rgb_angle_deg).abs() <= o.rank_tie_deg
        && (a.relative_error - b.relative_error).abs() <= o.same_render * a.relative_error.max(b.relative_error)
}

/// The mean angle (degrees) between rendered and photographed RGB over the
/// data pixels: the probe's colour pattern (a label) in the right place or
/// not, whatever detail of the lighting a coarse map leaves unexplained
/// (which moves intensity far more than hue).
pub(in crate::estimate) fn mean_rgb_angle_deg(rendered: &[[f64; 3]], target: &[[f64; 3]], weight: &[[f64; 3]]) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for ((r, t), w) in rendered.iter().zip(target).zip(weight) {
        if w.iter().any(|&w| w > 0.0) {
            let f = |v: &[f64; 3]| v.map(|x| x as f32);
            sum += crate::eval::rgb_angle_deg(f(r), f(t));
            n += 1;
        }
    }
    sum / n.max(1) as f64
}

/// The best-ranked of the starts `among` (the first of equals), by colour
/// ([`ranks_above`]), or for a probe `symmetric` about its axis, which has
/// no pattern to rank, by silhouette loss. Colour ranks only the starts
/// whose outline fits within `OrientationSettings::axis_keep_ratio` of the best start's (all
/// of them when none does): a probe's turns show one outline when it is of
/// revolution, and the kept axes fit within that ratio; a mug's handle
/// shows its turn in the outline, which a coarse map's colours can
/// contradict (its true turn's outline can fit several times better than
/// the turn colour ranks first).
pub(in crate::estimate) fn best_ranked(
    starts: &[StartReport],
    among: impl IntoIterator<Item = usize>,
    symmetric: bool,
    o: &OrientationSettings,
) -> Option<usize> {
    let among: Vec<usize> = among.into_iter().collect();
    let least = starts.iter().map(|s| s.silhouette_loss).fold(f64::INFINITY, f64::min);
    let fitting: Vec<usize> = among
        .iter()
        .copied()
        .filter(|&k| starts[k].silhouette_loss <= o.axis_keep_ratio * least)
        .collect();
    let among = if fitting.is_empty() { among } else { fitting };
    among.into_iter().reduce(|best, k| {
        let above = match symmetric {
            true => starts[k].silhouette_loss < starts[best].silhouette_loss,
            false => ranks_above(&starts[k], &starts[best], o),
        };
        if above { k } else { best }
    })
}

/// The rivals of start `chosen` (see `OrientationSettings::rival_rank_deg`): the best-ranked
/// start at the other end of the probe (its axis the other way) and the
/// best-ranked half a turn away about the same axis, each if it ranked
/// within the margin -- the other end whatever its rank where the probe's
/// colours are `colours_alike` all round (a grooved cap of one colour:
/// colour cannot tell its ends apart). Each kind's best, not only the better of the two: a
/// mask a pixel off turns how a probe's starts rank (a half turn of the
/// wrong end can rank above the right end, which the photo then scores
/// higher), and a small probe's end and half turn can both rank close.
pub(in crate::estimate) fn rival_starts(
    starts: &[StartReport],
    candidates: &[Pose],
    chosen: usize,
    colours_alike: bool,
    o: &OrientationSettings,
) -> Vec<usize> {
    let axis = candidates[chosen].rotation * Vec3::Y;
    let other_end = |k: usize| (candidates[k].rotation * Vec3::Y).dot(axis) < 0.0;
    let half_turn = |k: usize| {
        let turn = (starts[k].yaw_deg - starts[chosen].yaw_deg + 540.0).rem_euclid(360.0) - 180.0;
        !other_end(k) && starts[k].axis == starts[chosen].axis && turn.abs() > 90.0
    };
    let close = |k: usize| starts[k].rgb_angle_deg - starts[chosen].rgb_angle_deg <= o.rival_rank_deg;
    let best = |kind: &dyn Fn(usize) -> bool| best_ranked(starts, (0..starts.len()).filter(|&k| kind(k)), false, o);
    let end = best(&other_end).filter(|&k| colours_alike || close(k));
    let turn = best(&half_turn).filter(|&k| close(k));
    [end, turn].into_iter().flatten().collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimate::Settings;

    /// The default settings.
    fn o() -> OrientationSettings {
        Settings::default().orientation
    }
    use glam::Quat;

    /// A start's account with the ranking errors `rgb_angle_deg` and `relative_error`.
    fn start(rgb_angle_deg: f64, relative_error: f64) -> StartReport {
        StartReport {
            axis: 0,
            yaw_deg: 0.0,
            silhouette_loss: 1e-3,
            refitted: false,
            psnr_db: 30.0,
            rgb_angle_deg,
            relative_error,
            refinement: false,
        }
    }

    #[test]
    fn colour_ranks_only_the_starts_whose_outline_fits_near_the_best() {
        let with_outline = |rgb_angle_deg: f64, silhouette_loss: f64| StartReport {
            silhouette_loss,
            ..start(rgb_angle_deg, 0.2)
        };
        // A mug: the outline fits 8 times better at one turn (its handle
        // where the photo shows it) than at the turn colour ranks first.
        let mug = [
            with_outline(3.05, 0.0063),
            with_outline(4.0, 0.0008),
            with_outline(3.5, 0.0011),
        ];
        assert_eq!(best_ranked(&mug, 0..3, false, &o()), Some(2));
        // Among the others only, the best-ranked of them.
        assert_eq!(best_ranked(&mug, [0, 1], false, &o()), Some(1));
        // None fits near the best: colour ranks them all.
        assert_eq!(best_ranked(&mug, [0], false, &o()), Some(0));
        // Turns of a probe of revolution show one outline: colour decides.
        let can = [
            with_outline(3.05, 0.0010),
            with_outline(4.0, 0.0008),
            with_outline(3.5, 0.0011),
        ];
        assert_eq!(best_ranked(&can, 0..3, false, &o()), Some(0));
        // A symmetric probe goes by its outline alone.
        assert_eq!(best_ranked(&can, 0..3, true, &o()), Some(1));
    }

    #[test]
    fn turns_of_a_cap_of_one_colour_render_alike_and_turns_of_a_can_do_not() {
        // The first two turns of the tilted studio cap (its colour error is
        // small, so the facets move it by 1e-3 of itself; measured with the
        // outline soft mask) and of the tilted courtyard can, as the search
        // measured them.
        assert!(renders_alike(
            &start(2.114773668, 0.282519015),
            &start(2.112511746, 0.282515772),
            &o()
        ));
        assert!(!renders_alike(
            &start(11.640109023, 1.185091142),
            &start(12.560607700, 1.189073297),
            &o()
        ));
        // Colours that tie but relative errors 3e-3 apart: a pattern turned.
        assert!(!renders_alike(&start(5.0, 0.300), &start(5.01, 0.3009), &o()));
    }

    #[test]
    fn a_patterned_probe_s_rivals_are_its_best_starts_at_the_other_end_and_half_a_turn_away_if_they_ranked_close() {
        let start = |axis: usize, yaw_deg: f32, rgb_angle_deg: f64| StartReport {
            axis,
            yaw_deg,
            silhouette_loss: 1e-3,
            refitted: false,
            psnr_db: 30.0,
            rgb_angle_deg,
            relative_error: 0.5,
            refinement: false,
        };
        let turn = |yaw: f32| Quat::from_rotation_y(yaw.to_radians());
        let up = |yaw: f32| Pose::new(turn(yaw), 1.0, Vec3::ZERO);
        let down = |yaw: f32| Pose::new(Quat::from_rotation_x(std::f32::consts::PI) * turn(yaw), 1.0, Vec3::ZERO);
        let rivals = |angles: [f64; 4]| {
            let starts = [
                start(0, 10.0, angles[0]),
                start(0, 60.0, angles[1]),
                start(0, -170.0, angles[2]),
                start(1, 20.0, angles[3]),
            ];
            rival_starts(&starts, &[up(10.0), up(60.0), up(-170.0), down(20.0)], 0, false, &o())
        };
        // A nearby turn is no rival, however close it ranked; the best of
        // each kind that ranked close is.
        assert_eq!(
            rivals([10.0, 10.1, 10.6, 10.4]),
            [3, 2],
            "the other end and half a turn away"
        );
        assert_eq!(rivals([10.0, 10.1, 10.6, 11.5]), [2], "half a turn away");
        assert_eq!(rivals([10.0, 10.1, 11.1, 10.4]), [3], "the other end");
        assert_eq!(
            rivals([10.0, 10.1, 11.1, 11.5]),
            [0usize; 0],
            "both ranked too far behind"
        );
        // Colours alike all round cannot rank the ends: the other end is a
        // rival however far behind it ranked.
        let starts = [start(0, 10.0, 10.0), start(0, -170.0, 11.1), start(1, 20.0, 15.0)];
        let poses = [up(10.0), up(-170.0), down(20.0)];
        assert_eq!(rival_starts(&starts, &poses, 0, true, &o()), [2]);
        assert_eq!(rival_starts(&starts, &poses, 0, false, &o()), [0usize; 0]);
    }
}
