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
    assert!(
        s.refits >= 8 * 100,
        "characters were refitted: {}",
        s.refits
    );
    std::fs::remove_dir_all(out).ok();
}
