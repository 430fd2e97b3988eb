//! The declarative objective: composition and per-term reports, the JSON
//! file, weight schedules, gradient norms, and every built-in term's
//! gradients against finite differences (and a broken term failing them).

use std::path::PathBuf;
use std::sync::{Arc, OnceLock};

use alp::Result;
use alp::objective::testing::{Fixture, check_term};
use alp::objective::{
    Barycenter, Chamfer, LeastSquaresData, LightSmoothness, MaskL1, Objective, OrientationPrior, Phase, Phases, RgbL1,
    RgbVariant, Term, TermContext, Weight, Weighting,
};
use autodiff::{CustomOp, Tape, Var};
use render::colour::luminance;

/// Built once: every test reads the same scene.
fn fixture() -> &'static Fixture {
    static FIXTURE: OnceLock<Fixture> = OnceLock::new();
    FIXTURE.get_or_init(|| Fixture::new().expect("the fixture scene"))
}

/// Runs `f` on the fixture's context at `progress`, with the pose and the
/// env map as leaves (returned too, for gradients).
fn with_fixture<R>(
    progress: f64,
    f: impl for<'a, 't> FnOnce(&'t Tape<f64>, &TermContext<'a, 't>, [Var<'t, f64>; 2]) -> R,
) -> R {
    let fixture = fixture();
    let tape = Tape::new();
    let [pose, env] = fixture.parameters().map(|values| tape.leaf(&values));
    fixture
        .with_context(&tape, pose, env, progress, |ctx| f(&tape, ctx, [pose, env]))
        .expect("the fixture's context")
}

fn objectives_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../assets/objectives")
}

#[test]
fn every_built_in_term_passes_the_finite_difference_check() {
    let terms: Vec<Box<dyn Term>> = vec![
        Box::new(RgbL1::relative()),
        Box::new(RgbL1::new(RgbVariant::Plain)),
        Box::new(RgbL1::log()),
        Box::new(RgbL1::new(RgbVariant::Tonemapped)),
        Box::new(MaskL1),
        Box::new(Chamfer),
        Box::new(Barycenter),
        Box::new(OrientationPrior::front_facing()),
        Box::new(LightSmoothness::new(2.0)),
    ];
    for term in &terms {
        let check = check_term(term.as_ref(), fixture()).expect("the term applies");
        eprintln!("{check}");
        assert!(check.passes(), "{check}");
        assert!(check.value > 0.0, "{check}");
    }
}

/// `x^2` whose vector-Jacobian product forgets the factor 2.
struct BrokenSquare;

impl CustomOp<f64> for BrokenSquare {
    fn name(&self) -> &str {
        "broken_square"
    }
    fn output_len(&self, input_lens: &[usize]) -> usize {
        input_lens[0]
    }
    fn forward(&self, inputs: &[&[f64]], output: &mut [f64]) {
        for (y, x) in output.iter_mut().zip(inputs[0]) {
            *y = x * x;
        }
    }
    fn vjp(&self, inputs: &[&[f64]], _: &[f64], grad_output: &[f64], grad_inputs: &mut [Option<&mut [f64]>]) {
        if let Some(g) = grad_inputs[0].as_deref_mut() {
            for ((g, x), gy) in g.iter_mut().zip(inputs[0]).zip(grad_output) {
                *g += x * gy;
            }
        }
    }
}

/// The Chamfer distance squared, wrongly: by the broken op, or with one
/// factor's gradient cut.
enum WrongSquare {
    CustomOp,
    StopGradient,
}

impl Term for WrongSquare {
    fn name(&self) -> &str {
        "wrong_square"
    }
    fn evaluate<'t>(&self, ctx: &TermContext<'_, 't>) -> Result<Option<Var<'t, f64>>> {
        let Some(chamfer) = Chamfer.evaluate(ctx)? else {
            return Ok(None);
        };
        Ok(Some(match self {
            WrongSquare::CustomOp => ctx.tape.custom(Arc::new(BrokenSquare), &[chamfer]),
            WrongSquare::StopGradient => chamfer * chamfer.stop_gradient(),
        }))
    }
}

#[test]
fn the_check_fails_a_term_with_a_wrong_gradient() {
    for term in [WrongSquare::CustomOp, WrongSquare::StopGradient] {
        let check = check_term(&term, fixture()).expect("the term applies");
        eprintln!("{check}");
        assert!(!check.passes(), "a halved gradient must fail: {check}");
        assert!((check.pose.analytic / check.pose.numeric - 0.5).abs() < 1e-3, "{check}");
    }
}

#[test]
fn a_term_that_does_not_apply_on_the_fixture_is_an_error() {
    struct Never;
    impl Term for Never {
        fn name(&self) -> &str {
            "never"
        }
        fn evaluate<'t>(&self, _: &TermContext<'_, 't>) -> Result<Option<Var<'t, f64>>> {
            Ok(None)
        }
    }
    let e = check_term(&Never, fixture()).unwrap_err();
    assert!(
        e.to_string().contains("never") && e.to_string().contains("does not apply"),
        "{e}"
    );
}

#[test]
fn the_paper_default_composes_the_estimates_terms_and_reports_each() {
    let progress = 0.25;
    with_fixture(progress, |tape, ctx, _| {
        let eval = Objective::paper_default().evaluate(ctx).expect("an evaluation");
        let names: Vec<&str> = eval.terms.iter().map(|t| t.name.as_str()).collect();
        assert_eq!(
            names,
            ["rgb_l1", "mask_l1", "chamfer", "barycenter", "orientation",],
            "the pose phase's terms"
        );
        let weights: Vec<f64> = eval.terms.iter().map(|t| t.weight).collect();
        for (got, want) in weights.iter().zip([1.0, 1.0, 1.0, 5.0, 0.05]) {
            assert!((got - want).abs() < 1e-15, "{weights:?}");
        }
        let values = eval.values();
        let weighted: f64 = eval.terms.iter().map(|t| t.weight * values[&t.name]).sum();
        let total = tape.item(eval.total);
        assert!((total - weighted).abs() < 1e-12 * total, "{total} vs {weighted}");

        // The estimate's silhouette_loss, written out: L1 + Chamfer / diagonal
        // + (10 barycenter + 0.1 orientation) (1 - progress / 0.5).
        let soft = ctx.soft_mask.expect("the fixture records the soft mask");
        let diagonal = (96f64 * 96.0 + 72.0 * 72.0).sqrt();
        assert_eq!(tape.item(soft.mask_l1(ctx.reference).unwrap()), values["mask_l1"]);
        let chamfer = tape.item(soft.chamfer(ctx.reference).unwrap()) / diagonal;
        assert!((chamfer - values["chamfer"]).abs() < 1e-15, "{chamfer}");
        assert_eq!(weights[3], 10.0 * (1.0 - progress / 0.5));

        // The barycenter from the soft mask's image moments, in f64.
        let image = soft.to_image();
        let (mut m0, mut mx, mut my) = (0.0, 0.0, 0.0);
        for (i, m) in image.iter().enumerate() {
            m0 += m;
            mx += m * ((i % 96) as f64 + 0.5);
            my += m * ((i / 96) as f64 + 0.5);
        }
        let b = ctx.reference.barycenter();
        let barycenter = ((mx / m0 - b.x).powi(2) + (my / m0 - b.y).powi(2)) / (diagonal * diagonal);
        assert!((barycenter / values["barycenter"] - 1.0).abs() < 1e-9, "{barycenter}");

        // The orientation prior from glam's quaternions.
        let q = fixture().pose().rotation;
        let dot = q.dot(ctx.front_facing) as f64;
        assert!((1.0 - dot * dot - values["orientation"]).abs() < 1e-6);

        // The relative L1 from the rendered values, in f64: weights
        // 1 / (lum(t) + 0.05 level) on usable pixels, over 3 sum w.
        let image = ctx.image.expect("the fixture renders");
        let rendered = image.rendered().map(|c| tape.to_vec(c));
        let (mut sum, mut wsum) = (0.0, 0.0);
        for (p, (t, u)) in image.target().iter().zip(image.weight()).enumerate() {
            let w = u / (luminance(*t) + 0.05 * image.level());
            sum += w * (0..3).map(|c| (rendered[c][p] - t[c]).abs()).sum::<f64>();
            wsum += w;
        }
        let rgb = sum / (3.0 * wsum);
        assert!(
            (rgb / values["rgb_l1"] - 1.0).abs() < 1e-12,
            "{rgb} vs {}",
            values["rgb_l1"]
        );
    });
}

#[test]
fn terms_apply_only_where_their_inputs_are_recorded() {
    with_fixture(0.0, |_, ctx, _| {
        let objective = Objective::paper_default();
        let silhouette_only = TermContext {
            image: None,
            env: None,
            ..*ctx
        };
        let eval = objective.evaluate(&silhouette_only).expect("an evaluation");
        let names: Vec<&str> = eval.terms.iter().map(|t| t.name.as_str()).collect();
        assert_eq!(names, ["mask_l1", "chamfer", "barycenter", "orientation"]);
        let pose_only = TermContext {
            soft_mask: None,
            ..silhouette_only
        };
        let eval = objective.evaluate(&pose_only).expect("the orientation prior applies");
        assert_eq!(eval.terms.len(), 1);
        let e = Objective::new().term(RgbL1::log()).evaluate(&pose_only).unwrap_err();
        assert!(
            e.to_string()
                .contains("none of its pose phase's terms (rgb_l1_log) applies"),
            "{e}"
        );
    });
}

#[test]
fn weights_follow_the_progress_and_zero_weights_leave_the_total() {
    let objective = Objective::new()
        .term(Barycenter.weight(Weight::decay_to_zero(10.0, 0.5)))
        .term(Chamfer.weight(Weight::cosine_to_zero(2.0, 1.0)));
    for (progress, want) in [(0.0, [10.0, 2.0]), (0.25, [5.0, 1.7071067811865475]), (0.5, [0.0, 1.0])] {
        with_fixture(progress, |tape, ctx, _| {
            let eval = objective.evaluate(ctx).expect("an evaluation");
            let got: Vec<f64> = eval.terms.iter().map(|t| t.weight).collect();
            assert!(
                (got[0] - want[0]).abs() < 1e-12 && (got[1] - want[1]).abs() < 1e-12,
                "{got:?}"
            );
            let values = eval.values();
            let total = want[0] * values["barycenter"] + want[1] * values["chamfer"];
            assert!((tape.item(eval.total) - total).abs() < 1e-15);
        });
    }
    with_fixture(1.0, |tape, ctx, _| {
        let eval = Objective::new()
            .term(Chamfer.weight(0.0))
            .evaluate(ctx)
            .expect("an evaluation");
        assert_eq!((eval.terms.len(), tape.item(eval.total)), (1, 0.0));
    });
}

#[test]
fn gradient_norms_equal_each_terms_own_gradient() {
    let objective = Objective::paper_default();
    with_fixture(0.25, |tape, ctx, [pose, env]| {
        let eval = objective.evaluate(ctx).expect("an evaluation");
        let reports = eval.report(&[pose, env]).expect("leaves");
        // Afterwards the tape holds the total's gradient.
        let total_grad = tape.grad(pose).to_vec();
        for (t, report) in objective.terms().iter().zip(&reports) {
            // The term alone, recorded again on the same tape.
            let value = t.term().evaluate(ctx).unwrap().unwrap();
            tape.backward(value);
            let norm2: f64 = [pose, env]
                .iter()
                .flat_map(|v| tape.grad(*v).to_vec())
                .map(|g| g * g)
                .sum();
            let want = t.weight().at(0.25) * norm2.sqrt();
            eprintln!("{report:?}");
            assert!(want > 0.0, "{}: the gradient should not vanish", report.name);
            assert!(
                (report.gradient_norm.expect("measured") / want - 1.0).abs() < 1e-12,
                "{report:?} vs {want}"
            );
            assert_eq!(report.value, tape.item(value));
        }
        tape.backward(eval.total);
        assert_eq!(tape.grad(pose).to_vec(), total_grad);
        let constant = tape.constant(&[1.0]);
        assert!(eval.gradient_norms(&[constant]).is_err());
    });
}

#[test]
fn every_term_belongs_to_a_phase_that_records_what_it_reads() {
    let default = Objective::paper_default();
    assert_eq!(
        default.names_in(Phase::Pose),
        ["rgb_l1", "mask_l1", "chamfer", "barycenter", "orientation"]
    );
    assert_eq!(
        default.names_in(Phase::Lighting),
        ["data_least_squares", "neighbour_smoothness"]
    );
    // The RGB L1 may be minimised by both phases; the lighting phase
    // renders no soft mask and the pose phases hold the map fixed.
    let both = Objective::new().term(RgbL1::log().weight(1.0).in_phases(Phases::BOTH));
    assert!(both.validate().is_ok());
    assert_eq!(both.names_in(Phase::Lighting), ["rgb_l1_log"]);
    for (term, what) in [
        (
            Chamfer.weight(1.0).in_phases(Phases::LIGHTING),
            "it reads the soft mask",
        ),
        (
            LightSmoothness::new(2.0).weight(1.0).in_phases(Phases::POSE),
            "the env map as a variable",
        ),
        (
            LeastSquaresData.weight(1.0).in_phases(Phases::BOTH),
            "the lighting solve's data",
        ),
        (MaskL1.weight(1.0).in_phases(Phases::NONE), "evaluated by no phase"),
    ] {
        let name = term.term().name().to_string();
        let e = Objective::new().term(term).validate().unwrap_err();
        let message = e.to_string();
        assert!(message.contains(&name) && message.contains(what), "{message}");
    }
    // In a file, as `phases`.
    let text = r#"{"terms": [
        {"term": "rgb_l1", "phases": ["pose", "lighting"]},
        {"term": "neighbour_smoothness", "edge": 0.1, "chroma": 2.0, "weight": 0.02}
    ]}"#;
    let objective = Objective::from_json_str(text, "objective.json").expect("a valid objective");
    assert_eq!(objective.names_in(Phase::Lighting), ["rgb_l1", "neighbour_smoothness"]);
    assert_eq!(objective.names_in(Phase::Pose), ["rgb_l1"]);
    let text = "{\"terms\": [\n  {\"term\": \"chamfer\", \"phases\": [\"lighting\"]}\n]}";
    let e = Objective::from_json_str(text, "objective.json")
        .unwrap_err()
        .to_string();
    assert!(
        e.starts_with("objective.json") && e.contains("chamfer") && e.contains("lighting phase"),
        "{e}"
    );
    assert_file_error(
        "{\"terms\": [\n  {\"term\": \"mask_l1\", \"phases\": [\"light\"]}\n]}",
        2,
        "unknown phase `light`",
    );
}

#[test]
fn bad_contexts_and_weights_are_errors() {
    with_fixture(0.0, |_, ctx, _| {
        let late = TermContext { progress: 1.5, ..*ctx };
        let e = Objective::paper_default().evaluate(&late).unwrap_err();
        assert_eq!(e.field_name(), Some("progress"), "{e}");
        let e = Objective::new().term(Chamfer.weight(-1.0)).evaluate(ctx).unwrap_err();
        assert!(
            e.to_string().contains("chamfer weight") && e.to_string().contains("-1"),
            "{e}"
        );
        let e = Objective::new().evaluate(ctx).unwrap_err();
        assert!(e.to_string().contains("no terms"), "{e}");
        let lighting = TermContext {
            phase: Phase::Lighting,
            ..*ctx
        };
        let e = Objective::new()
            .term(LightSmoothness::new(-2.0))
            .evaluate(&lighting)
            .unwrap_err();
        assert_eq!(e.field_name(), Some("sigma_deg"), "{e}");
    });
}

#[test]
fn the_shipped_file_is_the_paper_default() {
    let from_file = Objective::from_file(objectives_dir().join("paper_default.json")).expect("a valid file");
    let built = Objective::paper_default();
    assert_eq!(format!("{from_file:?}"), format!("{built:?}"));
    with_fixture(0.3, |tape, ctx, _| {
        let (a, b) = (from_file.evaluate(ctx).unwrap(), built.evaluate(ctx).unwrap());
        assert_eq!(a.values(), b.values());
        assert_eq!(tape.item(a.total), tape.item(b.total));
    });
}

#[test]
fn a_good_file_gives_its_terms_and_weights() {
    let text = r#"{"terms": [
        {"term": "rgb_l1", "variant": "log"},
        {"term": "mask_l1"},
        {"term": "chamfer", "weight": 0.5},
        {"term": "barycenter", "weight": {"decay_to_zero": 10, "until": 0.5}},
        {"term": "orientation", "weight": {"decay_to_zero": 0.1, "until": 1.0, "shape": "cosine"}},
        {"term": "light_smoothness", "sigma_deg": 2.0, "weight": 1e-4}
    ]}"#;
    let objective = Objective::from_json_str(text, "objective.json").expect("a valid objective");
    let got: Vec<(&str, Weight)> = objective
        .terms()
        .iter()
        .map(|t| (t.term().name(), t.weight()))
        .collect();
    assert_eq!(
        got,
        [
            ("rgb_l1_log", Weight::Constant(1.0)),
            ("mask_l1", Weight::Constant(1.0)),
            ("chamfer", Weight::Constant(0.5)),
            ("barycenter", Weight::decay_to_zero(10.0, 0.5)),
            ("orientation", Weight::cosine_to_zero(0.1, 1.0)),
            ("light_smoothness", Weight::Constant(1e-4)),
        ]
    );
}

/// The error for `text` (terms on lines 2..), which must name `line` and say `what`.
fn assert_file_error(text: &str, line: usize, what: &str) {
    let e = Objective::from_json_str(text, "objective.json").expect_err(what);
    let message = e.to_string();
    eprintln!("{message}");
    assert!(message.starts_with("objective.json: "), "{message}");
    assert!(
        message.contains(&format!("line {line},")),
        "line {line} expected: {message}"
    );
    assert!(message.contains(what), "`{what}` expected: {message}");
}

#[test]
fn bad_files_are_errors_that_name_the_line() {
    let file = |terms: &str| format!("{{\"terms\": [\n  {{\"term\": \"mask_l1\"}},\n{terms}\n]}}");
    assert_file_error(&file("  {\"term\": \"mask_ll\"}"), 3, "unknown term `mask_ll`");
    assert_file_error(
        &file("  {\"term\": \"chamfer\",\n   \"wieght\": 2}"),
        4,
        "unknown field `wieght`",
    );
    assert_file_error(
        &file("  {\"term\": \"chamfer\", \"weight\": -1}"),
        3,
        "-1 must be finite and >= 0",
    );
    assert_file_error(
        &file("  {\"term\": \"barycenter\",\n   \"weight\": {\"decay_to_zero\": 10, \"until\": 0}}"),
        4,
        "must be in (0, 1]",
    );
    assert_file_error(
        &file("  {\"term\": \"barycenter\", \"weight\": {\"decay_to_zero\": 10, \"untill\": 0.5}}"),
        3,
        "unknown field `untill`",
    );
    assert_file_error(
        &file("  {\"term\": \"chamfer\", \"weight\": \"high\"}"),
        3,
        "invalid type",
    );
    assert_file_error(
        &file("  {\"term\": \"chamfer\",\n\n   \"sigma_deg\": 2}"),
        5,
        "does not apply to `chamfer`",
    );
    assert_file_error(&file("  {\"term\": \"light_smoothness\"}"), 3, "needs `sigma_deg`");
    assert_file_error(
        &file("  {\"term\": \"light_smoothness\",\n   \"sigma_deg\": 400}"),
        4,
        "must be in (0, 90] degrees",
    );
    assert_file_error(
        &file("  {\"term\": \"rgb_l1\", \"variant\": \"hdr\"}"),
        3,
        "unknown variant `hdr`",
    );
    assert_file_error(&file("  {\"term\": \"chamfer\",}"), 3, "key must be a string");
    assert_file_error("{\"terms\": [], \"scale\": 2}", 1, "unknown field `scale`");
    let e = Objective::from_json_str("{\"terms\": []}", "objective.json").unwrap_err();
    assert!(
        e.to_string().contains("objective.json") && e.to_string().contains("no terms"),
        "{e}"
    );
    let missing = objectives_dir().join("missing.json");
    let e = Objective::from_file(&missing).unwrap_err();
    assert!(e.to_string().contains("missing.json"), "{e}");
}

#[test]
fn a_file_declares_the_latitude_prior_and_its_bad_fields_are_errors() {
    let text = r#"{"terms": [
        {"term": "data_least_squares"},
        {"term": "latitude_prior", "weight": 0.02}
    ]}"#;
    let objective = Objective::from_json_str(text, "objective.json").expect("a valid objective");
    assert_eq!(
        objective.names_in(Phase::Lighting),
        ["data_least_squares", "latitude_prior"]
    );
    assert_file_error(
        "{\"terms\": [\n  {\"term\": \"latitude_prior\", \"edge\": 0.1}\n]}",
        2,
        "only to `neighbour_smoothness`",
    );
}
