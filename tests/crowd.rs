//! The crowd demo's code path, headless and small: it runs, queries behave, and it writes its images.

#[allow(dead_code)]
#[path = "../examples/crowd.rs"]
mod crowd;

#[test]
fn crowd_runs_120_frames_and_writes_pngs() {
    let out = std::env::temp_dir().join(format!("kinetrace-crowd-{}", std::process::id()));
    let opt = crowd::Options {
        characters: 8,
        triangles: 1_500,
        frames: 120,
        gpu: false,
        png_every: 60,
        out: out.clone(),
        width: 96,
        height: 54,
        ..Default::default()
    };
    let s = crowd::run(&opt).expect("the demo runs");
    assert_eq!(s.pngs.len(), 2);
    for p in &s.pngs {
        let img = image::open(p).expect("a PNG").to_rgb8();
        assert_eq!((img.width(), img.height()), (96, 54));
        // Not a blank image: sky, ground and characters give many colours.
        let mut colours: Vec<[u8; 3]> = img.pixels().map(|p| p.0).collect();
        colours.sort();
        colours.dedup();
        assert!(colours.len() > 20, "{} colours", colours.len());
    }
    assert_eq!(
        s.grounded_frames, 120,
        "the ground probe found the ground under everyone every frame"
    );
    assert_eq!(s.sight_checks, 8 * 2 * 120);
    // Two shadow rays and a reflection ray per probe hit, the ground filling most of the probe.
    let per_frame = s.secondary_rays / 120;
    assert!(
        s.secondary_rays.is_multiple_of(3) && per_frame > 3 * 48 * 27 / 2,
        "{per_frame}"
    );
    assert!(
        s.refits >= 8 * 100,
        "characters were refitted: {}",
        s.refits
    );
    std::fs::remove_dir_all(out).ok();
}

#[test]
fn debug_views_show_costs_and_boxes() {
    let opt = crowd::Options {
        characters: 6,
        triangles: 1_000,
        gpu: false,
        ..Default::default()
    };
    let (mut world, mut schedule) = crowd::setup(&opt).unwrap();
    for _ in 0..5 {
        crowd::step(&mut world, &mut schedule);
    }
    let cam = crowd::Camera::default();
    let shaded = crowd::render(&world, 120, 68, &cam, crowd::View::Shaded);
    let heat = crowd::render(&world, 120, 68, &cam, crowd::View::Heatmap);
    let boxes = crowd::render(&world, 120, 68, &cam, crowd::View::Boxes);
    // Heatmap: every pixel on the blue-to-red ramp (green stays low), and not all the same cost.
    assert!(
        heat.pixels().all(|p| p.0[1] <= 60),
        "heatmap colours leave the ramp"
    );
    let reds: Vec<u8> = heat.pixels().map(|p| p.0[0]).collect();
    assert!(reds.iter().max() > reds.iter().min(), "uniform heatmap");
    // Boxes: the shaded image with yellow box edges drawn over it, and nothing else changed.
    let yellow = [255, 220, 40];
    let drawn = boxes.pixels().filter(|p| p.0 == yellow).count();
    assert!(drawn > 50, "{drawn} box pixels");
    let changed = boxes
        .pixels()
        .zip(shaded.pixels())
        .filter(|(a, b)| a != b)
        .count();
    let over = boxes
        .pixels()
        .zip(shaded.pixels())
        .filter(|(a, b)| a != b && a.0 == yellow)
        .count();
    assert_eq!(changed, over);
}
