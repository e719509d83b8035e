//! Tests of `grid_map.rs`: small synthetic maps written to a temporary directory, and every map
//! in the repository's `maps/`.

use super::*;
use crate::Room;
use crate::caster::tests::{Tally, agree};
use crate::{EnvConfig, Lidar, LidarConfig, NavEnv, Pose2};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use std::path::Path;
use std::sync::Arc;

/// map_saver's values: free, occupied, unknown.
const FREE: u8 = 254;
const OCC: u8 = 0;
const UNK: u8 = 205;

/// A small map: an unknown border, walls, a pillar and a wall stub.
const ART: [&str; 9] = [
    "????????????",
    "?##########?",
    "?#........#?",
    "?#..##....#?",
    "?#..##..#.#?",
    "?#.......##?",
    "?#........#?",
    "?##########?",
    "????????????",
];

fn art() -> (u32, u32, Vec<u8>) {
    let px = ART
        .iter()
        .flat_map(|row| {
            row.chars().map(|c| match c {
                '#' => OCC,
                '.' => FREE,
                _ => UNK,
            })
        })
        .collect();
    (ART[0].len() as u32, ART.len() as u32, px)
}

fn write_p5(path: &Path, w: u32, h: u32, px: &[u8]) {
    let mut bytes = format!("P5\n# CREATOR: a test\n{w} {h}\n255\n").into_bytes();
    bytes.extend_from_slice(px);
    std::fs::write(path, bytes).unwrap();
}

fn write_p2(path: &Path, w: u32, h: u32, px: &[u8]) {
    let mut text = format!("P2\n{w} {h}\n255\n");
    for row in px.chunks(w as usize) {
        let row: Vec<String> = row.iter().map(|v| v.to_string()).collect();
        text += &row.join(" ");
        text += "\n";
    }
    std::fs::write(path, text).unwrap();
}

fn write_png_grey(path: &Path, w: u32, h: u32, px: &[u8]) {
    image::GrayImage::from_raw(w, h, px.to_vec()).unwrap().save(path).unwrap();
}

/// A map file next to `image`: its `image` line, then the `extra` lines, then the defaults of
/// the keys `extra` does not set.
fn write_yaml(dir: &Path, name: &str, image: &str, extra: &str) -> PathBuf {
    let mut text = format!("image: {image}\n{extra}");
    let defaults = [
        ("mode", "trinary"),
        ("resolution", "0.1"),
        ("origin", "[-2.0, -3.0, 0.0]"),
        ("negate", "0"),
        ("occupied_thresh", "0.65"),
        ("free_thresh", "0.196"),
    ];
    for (k, v) in defaults {
        if line_of_key(extra, k).is_none() {
            text += &format!("{k}: {v}\n");
        }
    }
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

fn name(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn trinary_thresholds_and_negate_classify_like_map_server() {
    let meta = MapMeta::for_image("x.png".into(), 0.05);
    let grey = |v: u8| [v, v, v, 255];
    let c = |m: &MapMeta, px: [u8; 4]| m.classify(px, false);
    assert_eq!(c(&meta, grey(255)), Cell::Free);
    assert_eq!(c(&meta, grey(206)), Cell::Free, "p = 49/255 < 0.196");
    assert_eq!(c(&meta, grey(205)), Cell::Unknown, "map_saver's grey: p = 50/255 > 0.196");
    assert_eq!(c(&meta, grey(90)), Cell::Unknown, "p = 165/255 < 0.65");
    assert_eq!(c(&meta, grey(89)), Cell::Occupied, "p = 166/255 > 0.65");
    assert_eq!(c(&meta, grey(0)), Cell::Occupied);
    // Colour: the mean of the channels.
    assert_eq!(c(&meta, [255, 0, 0, 255]), Cell::Occupied, "mean 85: p = 2/3");
    assert_eq!(c(&meta, [255, 255, 0, 255]), Cell::Unknown, "mean 170: p = 1/3");
    // Alpha is averaged in, in trinary mode: white but transparent is not free.
    assert_eq!(meta.classify([255, 255, 255, 0], true), Cell::Unknown, "p = 1/4");
    assert_eq!(meta.classify([255, 255, 255, 255], true), Cell::Free);

    let neg = MapMeta { negate: true, ..meta.clone() };
    assert_eq!(c(&neg, grey(0)), Cell::Free);
    assert_eq!(c(&neg, grey(255)), Cell::Occupied);
    assert_eq!(c(&neg, grey(50)), Cell::Unknown, "p = 50/255");
    assert_eq!(c(&neg, grey(49)), Cell::Free);

    let scale = MapMeta { mode: Mode::Scale, ..meta.clone() };
    assert_eq!(scale.classify([254, 254, 254, 255], true), Cell::Free);
    assert_eq!(scale.classify([254, 254, 254, 254], true), Cell::Unknown, "not opaque");
    assert_eq!(scale.classify([0, 0, 0, 255], true), Cell::Occupied);
    assert_eq!(c(&scale, grey(150)), Cell::Unknown, "graded: counts as unknown");

    let raw = MapMeta { mode: Mode::Raw, ..meta.clone() };
    assert_eq!(c(&raw, grey(0)), Cell::Free, "0 %");
    assert_eq!(c(&raw, grey(19)), Cell::Free, "19 % < 19.6 %");
    assert_eq!(c(&raw, grey(50)), Cell::Unknown);
    assert_eq!(c(&raw, grey(66)), Cell::Occupied);
    assert_eq!(c(&raw, grey(100)), Cell::Occupied);
    assert_eq!(c(&raw, grey(101)), Cell::Unknown, "beyond 100 %");
    assert_eq!(c(&raw, grey(255)), Cell::Unknown);
    let raw_neg = MapMeta { negate: true, ..raw };
    assert_eq!(c(&raw_neg, grey(0)), Cell::Free, "raw ignores negate, as map_server");
}

#[test]
fn a_negated_map_file_reads_the_inverted_image_as_the_same_room() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h, px) = art();
    write_p5(&dir.path().join("a.pgm"), w, h, &px);
    let inverted: Vec<u8> = px.iter().map(|v| 255 - v).collect();
    write_p5(&dir.path().join("b.pgm"), w, h, &inverted);
    let a = load(name(&write_yaml(dir.path(), "a.yaml", "a.pgm", ""))).unwrap();
    let b = load(name(&write_yaml(dir.path(), "b.yaml", "b.pgm", "negate: 1\n"))).unwrap();
    assert_eq!(a.grid, b.grid);
    assert_eq!(a.spec.obstacles, b.spec.obstacles);
    let c = load(name(&write_yaml(dir.path(), "c.yaml", "b.pgm", "negate: true\n"))).unwrap();
    assert_eq!(a.grid, c.grid);
}

#[test]
fn pgm_p5_p2_and_png_give_the_same_room() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h, px) = art();
    write_p5(&dir.path().join("p5.pgm"), w, h, &px);
    write_p2(&dir.path().join("p2.pgm"), w, h, &px);
    write_png_grey(&dir.path().join("grey.png"), w, h, &px);
    let rgb: Vec<u8> = px.iter().flat_map(|&v| [v, v, v]).collect();
    image::RgbImage::from_raw(w, h, rgb).unwrap().save(dir.path().join("rgb.png")).unwrap();
    // Opaque RGBA in scale mode reads like grey in trinary mode (trinary would average the
    // opacity in, as map_server does).
    let rgba: Vec<u8> = px.iter().flat_map(|&v| [v, v, v, 255]).collect();
    image::RgbaImage::from_raw(w, h, rgba).unwrap().save(dir.path().join("rgba.png")).unwrap();
    let grey_alpha: Vec<u8> = px.iter().flat_map(|&v| [v, 255]).collect();
    image::GrayAlphaImage::from_raw(w, h, grey_alpha)
        .unwrap()
        .save(dir.path().join("la.png"))
        .unwrap();

    let reference = load(name(&write_yaml(dir.path(), "p5.yaml", "p5.pgm", ""))).unwrap();
    for (image, extra) in [
        ("p2.pgm", ""),
        ("grey.png", ""),
        ("rgb.png", ""),
        ("rgba.png", "mode: scale\n"),
        ("la.png", "mode: scale\n"),
    ] {
        let yaml = write_yaml(dir.path(), &format!("{image}.yaml"), image, extra);
        let map = load(name(&yaml)).unwrap();
        assert_eq!(map.grid, reference.grid, "{image}");
        assert_eq!(map.spec.obstacles, reference.spec.obstacles, "{image}");
        assert_eq!(map.spec.side, reference.spec.side, "{image}");
    }
    // The art's free cells span columns 2..10 and rows 2..7: cropped to one more cell around.
    assert_eq!(reference.frame.crop, [1, 1, 11, 8]);
    assert!((reference.spec.side - 1.0).abs() < 1e-12, "10 x 7 cells at 0.1 m");
    assert_eq!(reference.spec.name, "p5");
    // The image alone (no map file) at the same resolution: the same room in its own frame.
    let alone = load(&format!("{}:resolution=0.1", name(&dir.path().join("grey.png")))).unwrap();
    assert_eq!(alone.spec.obstacles, reference.spec.obstacles);
    assert_eq!(alone.spec.name, "grey");
    assert_eq!(alone.meta.origin, [0.0; 3]);
}

/// A random grid: rooms of free space joined by gaps, speckle, unknown around.
fn random_grid(rng: &mut Pcg64, w: usize, h: usize) -> Vec<u8> {
    let mut px = vec![UNK; w * h];
    for _ in 0..rng.random_range(3..9) {
        let (x0, y0) = (rng.random_range(1..w - 2), rng.random_range(1..h - 2));
        let (x1, y1) = (rng.random_range(x0 + 1..w), rng.random_range(y0 + 1..h));
        for y in y0..y1 {
            for x in x0..x1 {
                px[y * w + x] = FREE;
            }
        }
        // Its walls.
        for x in x0.saturating_sub(1)..(x1 + 1).min(w) {
            for y in [y0.saturating_sub(1), y1.min(h - 1)] {
                if px[y * w + x] != FREE {
                    px[y * w + x] = OCC;
                }
            }
        }
    }
    for _ in 0..(w * h / 40) {
        let i = rng.random_range(0..w * h);
        px[i] = [OCC, FREE, UNK, 100][rng.random_range(0..4)];
    }
    px
}

#[test]
fn rectangles_cover_every_obstacle_cell_once_and_no_free_cell() {
    let mut rng = Pcg64::seed_from_u64(5);
    let dir = tempfile::tempdir().unwrap();
    for k in 0..12 {
        let (w, h) = (rng.random_range(4..70), rng.random_range(4..70));
        let px = random_grid(&mut rng, w, h);
        let image = format!("r{k}.pgm");
        write_p5(&dir.path().join(&image), w as u32, h as u32, &px);
        let res = [0.05, 0.1, 0.03][k % 3];
        let yaml = write_yaml(
            dir.path(),
            &format!("r{k}.yaml"),
            &image,
            &format!("resolution: {res}\norigin: [1.5, -0.25, 0.3]\n"),
        );
        let map = load(name(&yaml)).unwrap();
        let [c0, r0, c1, r1] = map.frame.crop;
        // Each obstacle cell of the crop lies in exactly one rectangle, free cells in none.
        let mut covered = vec![0u32; w * h];
        for [a, t, b, u] in map.grid.rectangles(map.frame.crop) {
            for r in t..u {
                for c in a..b {
                    covered[r * w + c] += 1;
                }
            }
        }
        for r in r0..r1 {
            for c in c0..c1 {
                let want = map.grid.at(c, r).is_obstacle() as u32;
                assert_eq!(covered[r * w + c], want, "map {k}, cell ({c}, {r})");
            }
        }
        // The boxes in the room: the centre of every obstacle cell of the crop is in one, of
        // every free cell in none; every free cell is inside the crop.
        let boxes = &map.spec.obstacles;
        for r in 0..h {
            for c in 0..w {
                let p = map.frame.cell_center(c, r);
                let inside = boxes.iter().filter(|b| b.contains(p)).count();
                let in_crop = (c0..c1).contains(&c) && (r0..r1).contains(&r);
                match map.grid.at(c, r) {
                    Cell::Free => {
                        assert!(in_crop, "map {k}: free cell ({c}, {r}) outside the crop");
                        assert_eq!(inside, 0, "map {k}: free cell ({c}, {r}) in a box");
                    }
                    _ if in_crop => assert_eq!(inside, 1, "map {k}: cell ({c}, {r})"),
                    _ => {}
                }
            }
        }
        // The square beside the crop is padded.
        let (side, res) = (map.spec.side, map.meta.resolution);
        let (cw, ch) = ((c1 - c0) as f64 * res, (r1 - r0) as f64 * res);
        for sgn in [-1.0, 1.0] {
            let p = if cw < side - 1e-9 {
                [sgn * (cw + side) / 4.0, 0.0]
            } else if ch < side - 1e-9 {
                [0.0, sgn * (ch + side) / 4.0]
            } else {
                continue;
            };
            assert!(boxes.iter().any(|b| b.contains(p)), "map {k}: {p:?} not padded");
        }
        // Far fewer boxes than cells.
        let obstacle_cells = (r0..r1)
            .flat_map(|r| (c0..c1).map(move |c| (c, r)))
            .filter(|&(c, r)| map.grid.at(c, r).is_obstacle())
            .count();
        assert!(boxes.len() <= obstacle_cells + 2, "map {k}");
        Room::try_new(map.spec.clone()).unwrap();
    }
}

#[test]
fn map_and_room_frames_convert_both_ways() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h, px) = art();
    write_p5(&dir.path().join("a.pgm"), w, h, &px);
    for yaw in [0.0, 0.7] {
        let yaml =
            write_yaml(dir.path(), "a.yaml", "a.pgm", &format!("origin: [-2.0, -3.0, {yaw}]\n"));
        let map = load(name(&yaml)).unwrap();
        let f = &map.frame;
        for p in [[0.0, 0.0], [1.25, -7.5], [-2.0, -3.0]] {
            let q = f.room_to_map(f.map_to_room(p));
            assert!((q[0] - p[0]).abs() < 1e-12 && (q[1] - p[1]).abs() < 1e-12, "{p:?}");
        }
        // The pillar's top-left cell (column 4, row 3) in the map frame: origin + R(yaw) ·
        // ((4.5, 9 − 3.5) · 0.1).
        let (s, c) = f64::sin_cos(yaw);
        let g = [0.45, 0.55];
        let m = [-2.0 + c * g[0] - s * g[1], -3.0 + s * g[0] + c * g[1]];
        let q = f.map_to_room(m);
        let want = f.cell_center(4, 3);
        assert!((q[0] - want[0]).abs() < 1e-12 && (q[1] - want[1]).abs() < 1e-12);
        let room = Room::try_new(map.spec.clone()).unwrap();
        assert!(room.circle_collides(q, 0.01), "the pillar is there");
        assert!(!room.circle_collides(f.cell_center(3, 2), 0.04), "free floor");
        assert!((f.map_yaw_to_room(yaw + 0.5) - 0.5).abs() < 1e-12);
        if yaw == 0.0 {
            // The description states the offset: the room's origin is the crop's centre.
            let o = f.room_to_map([0.0, 0.0]);
            assert!((o[0] - (-2.0 + 0.6)).abs() < 1e-12 && (o[1] - (-3.0 + 0.45)).abs() < 1e-12);
            assert!(map.spec.description.contains("map point (-1.4000, -2.5500)"), "{map:?}");
        }
    }
}

#[test]
fn lidar_on_a_loaded_map_matches_the_rapier_reference() {
    let mut rng = Pcg64::seed_from_u64(8);
    let dir = tempfile::tempdir().unwrap();
    let lidar = Lidar::new(&LidarConfig::default());
    let mut tally = Tally::default();
    for k in 0..3 {
        let (w, h) = (160, 120);
        let px = random_grid(&mut rng, w, h);
        let image = format!("m{k}.png");
        write_png_grey(&dir.path().join(&image), w as u32, h as u32, &px);
        let yaml = write_yaml(dir.path(), &format!("m{k}.yaml"), &image, "resolution: 0.05\n");
        let map = load(name(&yaml)).unwrap();
        let room = Room::try_new(map.spec.clone()).unwrap();
        assert!(room.caster().has_grid(), "{} boxes: enough to cull", map.spec.obstacles.len());
        let free: Vec<(usize, usize)> = (0..h)
            .flat_map(|r| (0..w).map(move |c| (c, r)))
            .filter(|&(c, r)| map.grid.at(c, r) == Cell::Free)
            .collect();
        for _ in 0..60 {
            let (c, r) = free[rng.random_range(0..free.len())];
            let p = map.frame.cell_center(c, r);
            let j = 0.45 * 0.05;
            let pose = Pose2::new(
                p[0] + rng.random_range(-j..j),
                p[1] + rng.random_range(-j..j),
                rng.random_range(-3.2..3.2),
            );
            // Every beam as rapier's, or as an exact f64 oracle where rapier's f32 cast is
            // ill-conditioned (grazing a corner); poses on a boundary are left out.
            agree(&room, &lidar, pose, &mut tally);
        }
        // And some poses anywhere, inside obstacles too.
        for _ in 0..30 {
            let hs = room.side() / 2.0;
            let pose = Pose2::new(rng.random_range(-hs..hs), rng.random_range(-hs..hs), 0.3);
            agree(&room, &lidar, pose, &mut tally);
        }
    }
    assert!(tally.poses > 200 && tally.inside > 10, "{tally:?}");
    assert!(tally.grazing * 1000 < tally.beams, "{tally:?}");
}

/// The error for map file `yaml` (or a name), which must cite the file and `key`.
fn refused(name: &str, key: &str) -> SpecFileError {
    let e = load(name).expect_err(name);
    assert_eq!(e.key, key, "{name}: {e}");
    let path = name.find(".png:").map_or(name, |i| &name[..i + 4]);
    let file = Path::new(path).file_name().unwrap();
    assert!(e.source.ends_with(file.to_str().unwrap()), "{name}: {e}");
    assert!(e.to_string().contains(&format!("`{key}`")) || key.is_empty(), "{e}");
    e
}

#[test]
fn bad_maps_are_refused_naming_the_file_and_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let (w, h, px) = art();
    write_p5(&d.join("ok.pgm"), w, h, &px);
    let yaml = |file: &str, image: &str, extra: &str| {
        write_yaml(d, file, image, extra).to_str().unwrap().to_string()
    };

    let e = refused(&yaml("gone.yaml", "nowhere.pgm", ""), "image");
    assert!(e.reason.contains(&d.join("nowhere.pgm").display().to_string()), "{e}");
    std::fs::write(d.join("junk.png"), b"not an image at all").unwrap();
    let e = refused(&yaml("junk.yaml", "junk.png", ""), "image");
    assert!(e.reason.contains("junk.png"), "{e}");
    std::fs::write(d.join("cut.png"), &std::fs::read(d.join("ok.pgm")).unwrap()[..20]).unwrap();
    refused(&yaml("cut.yaml", "cut.png", ""), "image");
    for r in ["0", "-0.05", ".nan", ".inf"] {
        let e = refused(&yaml("res.yaml", "ok.pgm", &format!("resolution: {r}\n")), "resolution");
        assert!(e.line.is_some(), "{e}");
    }
    let e = refused(&yaml("occ.yaml", "ok.pgm", "occupied_thresh: 1.5\n"), "occupied_thresh");
    assert_eq!(e.line, Some(2), "{e}");
    refused(&yaml("free.yaml", "ok.pgm", "free_thresh: -0.1\n"), "free_thresh");
    let e = refused(
        &yaml("order.yaml", "ok.pgm", "free_thresh: 0.7\noccupied_thresh: 0.6\n"),
        "free_thresh",
    );
    assert!(e.reason.contains("below occupied_thresh"), "{e}");
    let e = refused(&yaml("typo.yaml", "ok.pgm", "occupied_tresh: 0.6\n"), "occupied_tresh");
    assert!(e.line.is_some() && e.reason.contains("unknown key"), "{e}");
    refused(&yaml("origin.yaml", "ok.pgm", "origin: [1.0, 2.0]\n"), "origin");
    refused(&yaml("negate.yaml", "ok.pgm", "negate: 2\n"), "negate");
    refused(&yaml("mode.yaml", "ok.pgm", "mode: fancy\n"), "mode");
    refused(&yaml("kind.yaml", "ok.pgm", "resolution: fine\n"), "resolution");
    std::fs::write(d.join("short.yaml"), "image: ok.pgm\norigin: [0, 0, 0]\n").unwrap();
    refused(d.join("short.yaml").to_str().unwrap(), "resolution");

    write_p5(&d.join("black.pgm"), 3, 2, &[0; 6]);
    let e = refused(&yaml("black.yaml", "black.pgm", ""), "image");
    assert!(e.reason.contains("no free cell"), "{e}");
    write_png_grey(&d.join("wide.png"), MAX_SIDE_PX + 1, 1, &vec![FREE; MAX_SIDE_PX as usize + 1]);
    let e = refused(&yaml("wide.yaml", "wide.png", ""), "image");
    assert!(e.reason.contains("4001 x 1 px"), "{e}");

    // An image named alone.
    write_png_grey(&d.join("plain.png"), w, h, &px);
    let plain = d.join("plain.png").to_str().unwrap().to_string();
    refused(&format!("{plain}:resolution=0"), "resolution");
    refused(&format!("{plain}:resolution=wide"), "resolution");
    refused(&format!("{plain}:scale=2"), "scale");
    refused(d.join("absent.png").to_str().unwrap(), "image");
    // Through Room::load, the error is the same.
    let e = Room::load(&yaml("occ2.yaml", "ok.pgm", "occupied_thresh: 2\n")).unwrap_err();
    assert!(e.to_string().contains("occ2.yaml:2: `occupied_thresh`"), "{e}");
}

#[test]
fn room_load_reads_map_files_and_images() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h, px) = art();
    write_p5(&dir.path().join("x.pgm"), w, h, &px);
    let yaml = write_yaml(dir.path(), "x.yaml", "x.pgm", "");
    let rooms = Room::load(name(&yaml)).unwrap();
    assert_eq!(rooms.len(), 1);
    assert_eq!(rooms[0].name(), "x");
    assert!((rooms[0].side() - 1.0).abs() < 1e-12);
    // The same file as .yml, the image alone at 0.05 m/px (default) and at 0.1 m/px.
    std::fs::copy(&yaml, dir.path().join("x.yml")).unwrap();
    assert_eq!(Room::load(name(&dir.path().join("x.yml"))).unwrap()[0].name(), "x");
    let pgm = dir.path().join("x.pgm");
    assert!((Room::load(name(&pgm)).unwrap()[0].side() - 0.5).abs() < 1e-12);
    let at = format!("{}:resolution=0.1", name(&pgm));
    assert_eq!(Room::load(&at).unwrap()[0].spec().obstacles, rooms[0].spec().obstacles);
    assert!(is_map_name("a/b.YAML") && is_map_name("b.png:resolution=1") && !is_map_name("env0"));
}

#[test]
fn every_map_in_maps_loads_with_free_space_and_scans_like_rapier() {
    let maps = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../maps");
    let mut files: Vec<PathBuf> = std::fs::read_dir(&maps)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "yaml"))
        .collect();
    files.sort();
    assert!(files.len() >= 3, "maps/ holds {files:?}");
    let lidar = Lidar::new(&LidarConfig::default());
    let mut rng = Pcg64::seed_from_u64(3);
    for file in files {
        let map = load(name(&file)).unwrap();
        let free = map.grid.cells.iter().filter(|c| **c == Cell::Free).count();
        let area = free as f64 * map.meta.resolution.powi(2);
        assert!(area > 50.0, "{}: only {area} m² free", file.display());
        let room = Arc::new(Room::try_new(map.spec.clone()).unwrap());
        // Episodes can be drawn in it, and the scan agrees with rapier's.
        let mut env = NavEnv::new(room.clone(), &EnvConfig::default(), 1);
        env.reset();
        let mut tally = Tally::default();
        for _ in 0..30 {
            let h = room.side() / 2.0;
            let p = [rng.random_range(-h..h), rng.random_range(-h..h)];
            if room.circle_collides(p, 0.01) {
                continue;
            }
            agree(&room, &lidar, Pose2::new(p[0], p[1], rng.random_range(-3.2..3.2)), &mut tally);
        }
        assert!(
            tally.poses > 0 && tally.grazing * 1000 <= tally.beams,
            "{}: {tally:?}",
            file.display()
        );
        eprintln!(
            "{}: {} boxes, side {:.1} m, {area:.0} m² free",
            map.spec.name,
            map.spec.obstacles.len(),
            map.spec.side
        );
    }
}

#[test]
fn a_map_received_as_bytes_is_the_map_read_from_its_files() {
    let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/../../maps");
    let yaml = std::fs::read_to_string(format!("{dir}/aws_small_house.yaml")).unwrap();
    let image = std::fs::read(format!("{dir}/aws_small_house.png")).unwrap();
    let sent = from_bytes("SetMap", &yaml, &image).unwrap();
    let read = load(&format!("{dir}/aws_small_house.yaml")).unwrap();
    assert_eq!(sent.spec.obstacles, read.spec.obstacles);
    assert_eq!(sent.frame, read.frame);
    let e = from_bytes("SetMap", &yaml, &image[..100]).unwrap_err();
    assert_eq!(e.key, "image", "{e}");
    // The text need not name the image it comes with.
    let unnamed: String =
        yaml.lines().filter(|l| !l.starts_with("image")).collect::<Vec<_>>().join("\n");
    assert_eq!(from_bytes("SetMap", &unnamed, &image).unwrap().frame, read.frame);
    let e = from_bytes("SetMap", "resolution: 0.05\n", &image).unwrap_err();
    assert_eq!(e.key, "origin", "{e}");
}
