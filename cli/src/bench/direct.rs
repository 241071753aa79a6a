//! `bounce bench direct`: what direct light costs a light set while the lights move, turn, stay
//! put or dim, for several baked files side by side (a voxel-face bake, surface bakes at several
//! sample counts). Issue 17's cost target is this table's ratio to the voxel faces.
//!
//! The cost of a light set depends on the sets before it: a surface scene keeps each light
//! place's shadow-ray answers and the last set's blockers (`bounce_core::visibility`,
//! `bounce_core::coherence`), so a light that stays put costs next to nothing after its first
//! set, and one that moves a little finds most of its blockers on the first triangle it tries.
//! So every motion starts from a scene that remembers nothing, and the table shows the first
//! set apart from the later ones. Files and motions are measured in turn, round after round, so
//! that a machine's slow minute falls on all of them; the table shows medians over the rounds.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use bounce_core::format::Baked;
use bounce_core::light::{Light, LightSet};
use bounce_core::voxel::Geometry;
use bounce_engine::{Engine, EngineChoice};
use clap::Args;

use super::table::emit;

#[derive(Args, Debug)]
pub struct BenchDirectArgs {
    /// Baked files of one scene (`bounce bake`): a voxel-face bake among them is the baseline
    /// every ratio is taken against, else the first file.
    #[arg(required = true)]
    pub baked: Vec<PathBuf>,
    /// The light set every motion starts from, `{"lights": [...]}`; without it, the first
    /// file's own glTF lights.
    #[arg(long, value_name = "L.json")]
    pub lights: Option<PathBuf>,
    /// Motions, comma separated: `move` (point and spot lights step along +X), `turn`
    /// (directional and spot lights turn about +Y), `still` (the same set again) and `dim`
    /// (point, spot and directional lights 10% dimmer a set; skies and emissive surfaces stay).
    /// A motion that changes nothing in the light set is left out with a note.
    #[arg(long, value_delimiter = ',', default_value = "move,turn,still,dim")]
    pub motions: Vec<Motion>,
    /// Light sets a motion runs, one relight each (the first from a scene that keeps nothing).
    #[arg(long, default_value_t = 8)]
    pub sets: usize,
    /// Rounds over every file and motion; the table shows medians over them.
    #[arg(long, default_value_t = 3)]
    pub rounds: usize,
    /// How far a moving light steps a set, in scene units [default: a quarter of the baseline
    /// file's voxel size]. A step of a voxel or more leaves few of the last set's blockers in
    /// the way, and every set then costs about what a first one does.
    #[arg(long)]
    pub step: Option<f32>,
    /// How far a turning light turns a set, in degrees.
    #[arg(long, default_value_t = 2.0)]
    pub turn: f32,
    /// The engine timed: cpu, gpu or auto.
    #[arg(long, default_value = "cpu")]
    pub engine: String,
    /// Write the table as CSV here too.
    #[arg(long, value_name = "OUT.csv")]
    pub csv: Option<PathBuf>,
}

/// How a light set changes from one relight to the next.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Motion {
    Move,
    Turn,
    Still,
    Dim,
}

impl Motion {
    fn name(self) -> &'static str {
        match self {
            Motion::Move => "move",
            Motion::Turn => "turn",
            Motion::Still => "still",
            Motion::Dim => "dim",
        }
    }
}

/// The `k`-th set of `motion` from `base`: positions stepped `k · step` along +X, directions
/// turned `k · turn` radians about +Y, intensities `0.9^k` of theirs. Skies and emissive
/// changes stay as they are.
pub fn moved(base: &LightSet, motion: Motion, k: usize, step: f32, turn: f32) -> LightSet {
    let kf = k as f32;
    let (s, c) = (kf * turn).sin_cos();
    let turned = |d: [f32; 3]| [c * d[0] + s * d[2], d[1], -s * d[0] + c * d[2]];
    let dimmed = |i: f32| i * 0.9f32.powi(k as i32);
    let lights = base
        .lights
        .iter()
        .map(|light| {
            let mut light = light.clone();
            match (&mut light, motion) {
                (Light::Point { position, .. } | Light::Spot { position, .. }, Motion::Move) => {
                    position[0] += kf * step;
                }
                (
                    Light::Directional { direction, .. } | Light::Spot { direction, .. },
                    Motion::Turn,
                ) => *direction = turned(*direction),
                (
                    Light::Point { intensity, .. }
                    | Light::Spot { intensity, .. }
                    | Light::Directional { intensity, .. },
                    Motion::Dim,
                ) => *intensity = dimmed(*intensity),
                _ => {}
            }
            light
        })
        .collect();
    LightSet { lights }
}

/// Whether `motion` changes anything in `base` from one set to the next.
pub fn changes(base: &LightSet, motion: Motion) -> bool {
    base.lights.iter().any(|l| match motion {
        Motion::Move => matches!(l, Light::Point { .. } | Light::Spot { .. }),
        Motion::Turn => matches!(l, Light::Directional { .. } | Light::Spot { .. }),
        Motion::Dim => matches!(
            l,
            Light::Point { .. } | Light::Spot { .. } | Light::Directional { .. }
        ),
        Motion::Still => true,
    })
}

/// One file as the bench times it.
struct File {
    name: String,
    geometry: Geometry,
    samples: u32,
    voxel_size: f32,
    scene: bounce_engine::Scene,
}

/// Per (file, motion), per round: the first set's time and the later sets' mean, seconds.
#[derive(Default, Clone)]
struct Times {
    first: Vec<f64>,
    later: Vec<f64>,
    total: Vec<f64>,
}

pub fn run(args: &BenchDirectArgs) -> Result<()> {
    if args.sets < 2 || args.rounds == 0 {
        bail!("--sets must be at least 2 (a first set and later ones) and --rounds at least 1");
    }
    if !(args.turn.is_finite() && args.step.is_none_or(f32::is_finite)) {
        bail!("--step and --turn must be finite");
    }
    let choice: EngineChoice = args.engine.parse()?;
    let engine = Engine::new(choice)?;
    eprintln!("engine: {}", engine.describe());
    let mut files = Vec::new();
    let mut base = None;
    for path in &args.baked {
        let baked = Baked::read(path).with_context(|| format!("reading {}", path.display()))?;
        if base.is_none() {
            let set = match &args.lights {
                Some(p) => crate::lights_file::read(p)?,
                None if baked.meta.lights.is_empty() => bail!(
                    "{} has no lights of its own: give a light configuration with --lights L.json",
                    path.display()
                ),
                None => LightSet {
                    lights: baked.meta.lights.clone(),
                },
            };
            // Refused before the other files load (on `pandora`, seconds each).
            set.validate()
                .map_err(|e| anyhow::anyhow!("the light set: {e}"))?;
            base = Some(set);
        }
        let scene = engine
            .load(&baked)
            .with_context(|| format!("loading {}", path.display()))?;
        files.push(File {
            name: path.display().to_string(),
            geometry: baked.meta.settings.geometry,
            samples: engine.samples_for(&scene),
            voxel_size: baked.layout.voxel_size,
            scene,
        });
    }
    let Some(base) = base else {
        bail!("no baked file given");
    };
    let baseline = files
        .iter()
        .position(|f| f.geometry == Geometry::VoxelFaces)
        .unwrap_or(0);
    let step = args.step.unwrap_or(0.25 * files[baseline].voxel_size);
    let turn = args.turn.to_radians();
    let mut motions = Vec::new();
    for &m in &args.motions {
        if motions.contains(&m) {
            continue;
        }
        if changes(&base, m) {
            motions.push(m);
        } else {
            eprintln!(
                "  {}: left out, the light set has no light it changes",
                m.name()
            );
        }
    }
    if motions.is_empty() {
        bail!("no motion changes the light set");
    }
    eprintln!(
        "bench direct: {} file(s), motions {}, {} sets each, {} round(s); a step {step} units, a turn {}°; baseline {}",
        files.len(),
        motions
            .iter()
            .map(|m| m.name())
            .collect::<Vec<_>>()
            .join(","),
        args.sets,
        args.rounds,
        args.turn,
        files[baseline].name
    );
    let sets: Vec<Vec<LightSet>> = motions
        .iter()
        .map(|&m| {
            (0..args.sets)
                .map(|k| moved(&base, m, k, step, turn))
                .collect()
        })
        .collect();
    let mut times = vec![vec![Times::default(); motions.len()]; files.len()];
    for round in 0..args.rounds {
        for (m, sets) in sets.iter().enumerate() {
            for (f, file) in files.iter_mut().enumerate() {
                file.scene.forget_shadow_answers();
                let mut each = Vec::with_capacity(sets.len());
                for set in sets {
                    let (_, timing) = engine
                        .relight_timed(&file.scene, std::slice::from_ref(set))
                        .with_context(|| format!("relighting {}", file.name))?;
                    each.push(timing.direct_s);
                }
                let t = &mut times[f][m];
                t.first.push(each[0]);
                t.later
                    .push(each[1..].iter().sum::<f64>() / (each.len() - 1) as f64);
                t.total.push(each.iter().sum());
            }
        }
        eprintln!("  round {} of {} done", round + 1, args.rounds);
    }
    let header = [
        "file",
        "geometry",
        "samples",
        "motion",
        "sets",
        "first_ms",
        "later_ms_per_set",
        "total_ms",
        "total_x_baseline",
        "later_x_baseline",
    ];
    let mut rows = Vec::new();
    for (m, motion) in motions.iter().enumerate() {
        let base_total = median(&times[baseline][m].total);
        let base_later = median(&times[baseline][m].later);
        for (f, file) in files.iter().enumerate() {
            let t = &times[f][m];
            let (total, later) = (median(&t.total), median(&t.later));
            rows.push(vec![
                file.name.clone(),
                file.geometry.to_string(),
                file.samples.to_string(),
                motion.name().to_string(),
                args.sets.to_string(),
                format!("{:.2}", median(&t.first) * 1e3),
                format!("{:.2}", later * 1e3),
                format!("{:.2}", total * 1e3),
                ratio(total, base_total),
                ratio(later, base_later),
            ]);
        }
    }
    emit(&header, &rows, args.csv.as_deref())
}

fn ratio(a: f64, b: f64) -> String {
    if b > 0.0 {
        format!("{:.2}", a / b)
    } else {
        "-".to_string()
    }
}

fn median(v: &[f64]) -> f64 {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    match v.len() {
        0 => 0.0,
        n if n % 2 == 1 => v[n / 2],
        n => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn set() -> LightSet {
        LightSet::from_json(
            r#"{"lights": [
                {"type": "point", "position": [1, 2, 3], "intensity": 10},
                {"type": "directional", "direction": [1, -1, 0], "intensity": 2},
                {"type": "sky", "color": [0.1, 0.2, 0.3]}]}"#,
        )
        .unwrap()
    }

    #[test]
    fn each_motion_changes_only_its_own() {
        let base = set();
        assert_eq!(moved(&base, Motion::Still, 5, 1.0, 0.1), base);
        let m = moved(&base, Motion::Move, 3, 0.5, 0.1);
        let Light::Point { position, .. } = &m.lights[0] else {
            panic!("a point light")
        };
        assert_eq!(*position, [2.5, 2.0, 3.0]);
        assert_eq!(m.lights[1..], base.lights[1..], "only positions move");
        let t = moved(&base, Motion::Turn, 2, 0.5, std::f32::consts::FRAC_PI_4);
        let Light::Directional { direction, .. } = &t.lights[1] else {
            panic!("a directional light")
        };
        // A quarter turn about +Y takes +X to −Z, and keeps the length and the height.
        assert!((direction[0]).abs() < 1e-6 && (direction[2] + 1.0).abs() < 1e-6);
        assert_eq!(direction[1], -1.0);
        assert_eq!(t.lights[0], base.lights[0], "a point light does not turn");
        let d = moved(&base, Motion::Dim, 2, 0.5, 0.1);
        let Light::Point { intensity, .. } = &d.lights[0] else {
            panic!("a point light")
        };
        assert!((intensity - 8.1).abs() < 1e-5);
        assert_eq!(d.lights[2], base.lights[2], "a sky stays");
    }

    #[test]
    fn a_motion_that_changes_nothing_is_known() {
        let sky =
            LightSet::from_json(r#"{"lights": [{"type": "sky", "color": [1, 1, 1]}]}"#).unwrap();
        for m in [Motion::Move, Motion::Turn, Motion::Dim] {
            assert!(!changes(&sky, m), "{m:?}");
        }
        assert!(changes(&sky, Motion::Still));
        let base = set();
        assert!(changes(&base, Motion::Move) && changes(&base, Motion::Turn));
    }

    #[test]
    fn medians() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), 2.5);
        assert_eq!(ratio(1.0, 0.0), "-");
    }
}
