//! `dvnav transfer`: the dimension-scaled robot and μ for a varied-robot file (DVST, design
//! §5), as text, JSON, or the paper's illustration.

use crate::render::dvst::render_dvst;
use clap::Args;
use dvnav_config::EnvConfig;
use dvnav_nav::dvst::{Reach, VariedRobot, VelocityBounds};
use std::path::PathBuf;
use std::process::ExitCode;

/// `dvnav transfer`.
#[derive(Args, Debug)]
pub struct TransferArgs {
    /// The varied robot: a footprint file (`[[parts]]`), optionally with `margin`, `v_max`,
    /// `omega_max` and `[meta]` (see `footprints/`).
    #[arg(long)]
    footprint: PathBuf,
    /// Print one JSON object.
    #[arg(long)]
    json: bool,
    /// Draw the meta, varied and scaled robots to this PNG.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Drawing size in pixels.
    #[arg(long, default_value_t = 600)]
    size: u32,
}

/// What `dvnav transfer --json` prints.
#[derive(serde::Serialize)]
struct Report<'a> {
    /// The footprint file.
    file: String,
    footprint: &'a dvnav_sim::Footprint,
    /// The varied robot's reach from the axle along each axis (m).
    reach: Reach,
    /// Its farthest point from the axle centre (m).
    bounding_radius: f64,
    meta: dvnav_nav::dvst::MetaRobot,
    margin: f64,
    mu: f64,
    scaled: dvnav_nav::dvst::MetaRobot,
    v_max: f64,
    omega_max: f64,
    /// Where `v_max` comes from: `file`, or `meta` (the meta agent's, from the default run
    /// configuration).
    v_max_from: &'static str,
    /// Where `omega_max` comes from, likewise.
    omega_max_from: &'static str,
}

fn source(own: Option<f64>) -> &'static str {
    if own.is_some() { "file" } else { "meta" }
}

fn report(file: String, robot: &VariedRobot) -> Report<'_> {
    // The meta agent's bounds: the defaults of the run configuration it was trained with.
    let env = EnvConfig::default();
    let meta = VelocityBounds { v_max: env.v_max, omega_max: env.omega_max };
    let bounds = robot.velocity_bounds(meta);
    Report {
        file,
        footprint: &robot.footprint,
        reach: Reach::of(&robot.footprint),
        bounding_radius: robot.footprint.bounding_radius(),
        meta: robot.meta,
        margin: robot.margin,
        mu: robot.mu(),
        scaled: robot.scaled_robot(),
        v_max: bounds.v_max,
        omega_max: bounds.omega_max,
        v_max_from: source(robot.v_max),
        omega_max_from: source(robot.omega_max),
    }
}

/// Runs `dvnav transfer`.
pub fn run(args: TransferArgs) -> anyhow::Result<ExitCode> {
    anyhow::ensure!((64..=8192).contains(&args.size), "--size must be in 64..=8192 pixels");
    let robot = VariedRobot::load(&args.footprint)?;
    let report = report(args.footprint.display().to_string(), &robot);
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print_report(&report);
    }
    if let Some(out) = &args.out {
        if let Some(dir) = out.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir)?;
        }
        let canvas = render_dvst(&robot, args.size)?;
        std::fs::write(out, canvas.encode_png()?)?;
        eprintln!("dvnav transfer: {} ({}x{} px)", out.display(), canvas.width(), canvas.height());
    }
    Ok(ExitCode::SUCCESS)
}

fn print_report(r: &Report) {
    let name = if r.footprint.name.is_empty() {
        String::new()
    } else {
        format!(" ({})", r.footprint.name)
    };
    let kinds: Vec<&str> = r.footprint.parts.iter().map(|p| p.kind()).collect();
    let from = |s: &str| if s == "file" { "its own" } else { "the meta agent's" };
    let reach = r.reach;
    println!("{}{name}", r.file);
    let parts = if kinds.len() == 1 { "part" } else { "parts" };
    println!("  varied robot (DVR)  {} {parts}: {}", kinds.len(), kinds.join(", "));
    println!(
        "                      reach front {:.3}, back {:.3}, left {:.3}, right {:.3} m; \
         farthest point {:.3} m from the axle",
        reach.front, reach.back, reach.left, reach.right, r.bounding_radius
    );
    println!("  meta robot (MR)     {}", r.meta.describe());
    println!("  safety margin       {:.3} m", r.margin);
    println!("  mu                  {:.4}", r.mu);
    println!("  scaled robot (DSR)  {}", r.scaled.describe());
    println!("  v_max               {:.3} m/s ({})", r.v_max, from(r.v_max_from));
    println!("  omega_max           {:.3} rad/s ({})", r.omega_max, from(r.omega_max_from));
}

#[cfg(test)]
mod tests {
    use super::*;
    use dvnav_nav::dvst::MetaRobot;
    use std::path::Path;

    /// Every shipped footprint loads, and its μ is the one its comment states.
    #[test]
    fn shipped_footprints_give_their_stated_mu() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("footprints");
        let expect = [
            ("circle-0.5.toml", 2.5),
            ("small-0.15.toml", 0.75),
            ("paper-medium.toml", 1.85),
            ("circle-with-cargo.toml", (0.45f64.hypot(0.15) + 0.03) / 0.2),
            ("cart-with-cargo.toml", (0.35 + 0.03) / 0.2),
            ("rect-with-cargo.toml", (0.40f64.hypot(0.23) + 0.03) / 0.2),
            ("turtlebot2-hokuyo.toml", (0.177 + 0.05) / 0.2),
        ];
        let mut files: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        files.sort();
        let mut listed: Vec<String> = expect.iter().map(|(f, _)| f.to_string()).collect();
        listed.sort();
        assert_eq!(files, listed, "a test for every file in footprints/");
        for (file, mu) in expect {
            let robot = VariedRobot::load(&dir.join(file)).unwrap();
            robot.validate().unwrap();
            assert!((robot.mu() - mu).abs() < 1e-12, "{file}: mu {} != {mu}", robot.mu());
        }
        let tb2 = VariedRobot::load(&dir.join("turtlebot2-hokuyo.toml")).unwrap();
        assert_eq!((tb2.lidar.x, tb2.lidar.yaw), (0.1, 0.0));
        let cart = VariedRobot::load(&dir.join("cart-with-cargo.toml")).unwrap();
        let r = report("cart".into(), &cart);
        assert_eq!((r.v_max, r.omega_max, r.v_max_from), (0.4, 1.2, "file"));
        let MetaRobot::Rectangle { left, front, .. } = r.scaled else { panic!("{:?}", r.scaled) };
        assert!((left - 0.38).abs() < 1e-12 && (front - 0.25 * 1.9).abs() < 1e-12);
        let json = serde_json::to_value(&r).unwrap();
        assert!((json["mu"].as_f64().unwrap() - 1.9).abs() < 1e-12);
        assert_eq!(json["meta"]["shape"], "rectangle");
        assert_eq!(json["footprint"]["parts"].as_array().unwrap().len(), 2);
    }

    /// README § DVST shows `footprints/cart-with-cargo.toml` (comments aside).
    #[test]
    fn the_readme_example_is_the_shipped_cart() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let readme = std::fs::read_to_string(root.join("README.md")).unwrap();
        let dvst = &readme[readme.find("## DVST").expect("README has § DVST")..];
        let start = dvst.find("```toml\n").unwrap() + "```toml\n".len();
        let block = &dvst[start..start + dvst[start..].find("```").unwrap()];
        let shown = VariedRobot::from_toml_str(block, "README.md").unwrap();
        let file = VariedRobot::load(&root.join("footprints/cart-with-cargo.toml")).unwrap();
        assert_eq!(shown, file);
    }

    #[test]
    fn a_missing_or_bad_file_is_a_clear_error() {
        let args =
            |p: &Path| TransferArgs { footprint: p.into(), json: true, out: None, size: 600 };
        let e = run(args(Path::new("/nonexistent/robot.toml"))).unwrap_err();
        assert!(e.to_string().contains("/nonexistent/robot.toml: cannot read"), "{e}");
        let dir = tempfile::tempdir().unwrap();
        let bad = dir.path().join("bad.toml");
        std::fs::write(&bad, "margin = 0.1\n[[parts]]\nshape = \"circle\"\ncenter = [0.0, 0.0]\n")
            .unwrap();
        let e = run(args(&bad)).unwrap_err().to_string();
        assert!(e.contains("bad.toml:2") && e.contains("radius"), "{e}");
    }
}
