//! The lighting prior where the probe sees weakly: one scene seen through a
//! can with a saturated red label and through a silver one should give the
//! same map, and no map should carry speckle the photo does not demand.

use alp::estimate::{Photo, Quality, Settings, estimate};
use alp::eval::{relighting_errors, speckle};
use alp::relight::RelightSettings;
use alp::synth::{SynthSettings, synthesize};
use render::camera::Camera;
use render::envmap::EnvMap;
use render::probe::ProbeAsset;
use render::procedural::SodaCan;

/// The can with its label painted `label` (roughness 0.30) but for thin
/// bare stripes (roughness 0.12) every 16 texels round; the rest bare
/// aluminium.
fn can_labelled(label: [f32; 3]) -> ProbeAsset {
    let mut can = SodaCan::default().build();
    let width = can.albedo.image.width;
    let texels = can.albedo.image.pixels.iter_mut().zip(&mut can.roughness.image.pixels);
    for (k, (albedo, roughness)) in texels.enumerate() {
        if roughness[0] > 0.3 {
            let stripe = (k % width) % 16 == 0;
            *albedo = if stripe { SILVER } else { label };
            *roughness = [if stripe { 0.12 } else { 0.30 }; 3];
        } else {
            *albedo = SILVER;
        }
    }
    can
}

const SILVER: [f32; 3] = [0.91, 0.92, 0.92];

/// The courtyard map at `height` texels.
fn courtyard(height: usize) -> EnvMap {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/envmaps/courtyard.exr");
    EnvMap::read(path).expect("bundled env map").downsample(height)
}

/// The lighting estimated at the true pose from a 320x240 photo of `can`
/// with 2 % sensor noise, and the photo's camera.
fn estimated(can: &ProbeAsset, env: &EnvMap) -> (EnvMap, Camera) {
    let synth = SynthSettings {
        seed: 3,
        noise: 0.02,
        spp: 64,
        width: 320,
        height: 240,
        ..SynthSettings::default()
    };
    let scene = synthesize(can, env, &synth).expect("a photo");
    let photo = Photo::new(scene.image, scene.mask, scene.camera).expect("a valid photo");
    let mut settings = Settings::new(Quality::Default);
    settings.known_pose = Some(scene.pose);
    let result = estimate(&photo, can, &settings).expect("an estimate");
    (result.env, scene.camera)
}

#[test]
fn a_red_label_s_dim_channels_count_so_its_map_nears_a_silver_can_s_with_little_speckle() {
    let env = courtyard(128);
    let (red, camera) = estimated(&can_labelled([0.75, 0.10, 0.10]), &env);
    let (silver, _) = estimated(&can_labelled(SILVER), &env);
    // Both maps are solved at 256x128, the sharp stripes' resolution,
    // though most of what the probe shows comes through the rough label.
    assert_eq!((red.width(), red.height()), (256, 128));
    let settings = RelightSettings::default();
    let between = relighting_errors(&red, &silver, &camera, &settings).expect("relit")[0].angular_deg;
    // 12.5 deg with the channels weighted by luminance; 8.4 with each
    // channel weighted by its own level (issue 36 asks for 1: not met).
    assert!(between < 10.0, "the two maps are {between} deg apart (mirror)");
    // The true map has 0.04 % of such texels at this size. Weighted by
    // luminance, the red label's maps had 1.1 % (red channel) and the
    // silver's 1.9 %; per channel, 0.2 % and 1.2 %.
    for (name, map, most) in [("red", &red, 0.005), ("silver", &silver, 0.015)] {
        let share = speckle(map);
        assert!(
            share.iter().all(|&s| s < most),
            "{name}: {share:?} of the texels stand alone above their neighbours"
        );
    }
}
