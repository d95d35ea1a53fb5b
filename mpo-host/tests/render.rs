//! Rendering (`mpo render`, `mpo train --render-every`): MuJoCo's offscreen renderer on a real
//! task, the pictured returns against `mpo eval`'s, bit-identical repeats, the errors.
//!
//! Needs offscreen OpenGL (EGL; without a GPU, Mesa's software renderer from Debian's
//! libegl1 libegl-mesa0 libgl1-mesa-dri libgles2, which `.ci/run` installs).

mod common;
use common::*;

use std::path::Path;

use sim_bridge::render::Renderer;
use sim_bridge::{Environment, TaskDef};

/// Distinct colours in an RGB image.
fn colours(rgb: &[u8]) -> usize {
    let mut c: Vec<[u8; 3]> = rgb.chunks(3).map(|p| [p[0], p[1], p[2]]).collect();
    c.sort_unstable();
    c.dedup();
    c.len()
}

/// Pixels that differ between two RGB images.
fn differing(a: &[u8], b: &[u8]) -> usize {
    a.chunks(3).zip(b.chunks(3)).filter(|(x, y)| x != y).count()
}

/// The frames of a GIF as whole RGBA pictures (each later frame drawn over the previous one,
/// transparent pixels keeping what was there, as a player shows them), and the delays.
fn gif_frames(path: &Path) -> (u16, u16, Vec<Vec<u8>>, Vec<u16>) {
    let mut opts = gif::DecodeOptions::new();
    opts.set_color_output(gif::ColorOutput::RGBA);
    let mut d = opts.read_info(std::fs::File::open(path).unwrap()).unwrap();
    let (w, h) = (d.width(), d.height());
    let mut canvas = vec![0u8; w as usize * h as usize * 4];
    let (mut frames, mut delays) = (Vec::new(), Vec::new());
    while let Some(f) = d.read_next_frame().unwrap() {
        for y in 0..f.height as usize {
            for x in 0..f.width as usize {
                let src = &f.buffer[(y * f.width as usize + x) * 4..][..4];
                if src[3] != 0 {
                    let dst = ((f.top as usize + y) * w as usize + f.left as usize + x) * 4;
                    canvas[dst..dst + 4].copy_from_slice(src);
                }
            }
        }
        frames.push(canvas.clone());
        delays.push(f.delay);
    }
    (w, h, frames, delays)
}

/// Width, height and RGB bytes of a PNG.
fn png_rgb(path: &Path) -> (u32, u32, Vec<u8>) {
    let d = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut r = d.read_info().unwrap();
    let mut buf = vec![0; r.output_buffer_size().unwrap()];
    let info = r.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb);
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

#[test]
fn frames_of_a_real_task_have_the_size_show_the_scene_and_follow_the_state() {
    let (w, h) = (96, 64);
    let mut env = sim_bridge::SuiteEnv::new("cartpole-balance", 7).unwrap();
    let mut obs = [0.0; 5];
    env.reset(&mut obs);
    let mut a = Renderer::new(&TaskDef::builtin("cartpole-balance").unwrap(), w, h, None).unwrap();
    assert_eq!(a.camera(), "fixed");
    let mut frames = Vec::new();
    for _ in 0..3 {
        frames.push(a.render(env.physics()).unwrap().to_vec());
        for _ in 0..25 {
            env.step(&[1.0], &mut obs);
        }
    }
    for f in &frames {
        assert_eq!(f.len(), (w * h * 3) as usize);
        // Skybox, floor, rail, cart and pole: far more than a blank or one-colour image.
        assert!(colours(f) > 50, "{} colours", colours(f));
    }
    // The cart is pushed right for 25 steps between frames: the pictures change.
    assert!(differing(&frames[0], &frames[1]) > 20);
    assert!(differing(&frames[1], &frames[2]) > 20);

    // A second renderer (its own model and OpenGL context) draws the same state to the same
    // bytes: software rendering is deterministic.
    let mut b = Renderer::new(&TaskDef::builtin("cartpole-balance").unwrap(), w, h, None).unwrap();
    let again = b.render(env.physics()).unwrap().to_vec();
    assert_eq!(again, a.render(env.physics()).unwrap());

    // Larger than the model's 640x480 offscreen buffer: the renderer enlarges it, and the far
    // corner is drawn (floor), not left empty.
    let (bw, bh) = (700, 500);
    let mut big =
        Renderer::new(&TaskDef::builtin("cartpole-balance").unwrap(), bw, bh, None).unwrap();
    let img = big.render(env.physics()).unwrap();
    assert_eq!(img.len(), (bw * bh * 3) as usize);
    let corner = &img[(((bh - 20) * bw + bw - 20) * 3) as usize..][..60];
    assert!(
        corner.iter().any(|&c| c > 0),
        "bottom-right corner is black"
    );
}

#[test]
fn cameras_are_the_models_and_an_unknown_one_lists_them() {
    assert_eq!(
        sim_bridge::render::cameras(&TaskDef::builtin("walker-walk").unwrap()).unwrap(),
        ["side", "back", "free"]
    );
    let e = Renderer::new(
        &TaskDef::builtin("cartpole-balance").unwrap(),
        32,
        24,
        Some("nope"),
    )
    .unwrap_err();
    let text = e.to_string();
    assert!(
        text.contains("`nope`") && text.contains("fixed, lookatcart, free"),
        "{text}"
    );
    let r = Renderer::new(
        &TaskDef::builtin("hopper-stand").unwrap(),
        32,
        24,
        Some("back"),
    )
    .unwrap();
    assert_eq!(r.camera(), "back");
    assert!(Renderer::new(&TaskDef::builtin("hopper-stand").unwrap(), 0, 24, None).is_err());
}

#[test]
fn render_pictures_the_evaluated_returns_and_repeats_bit_for_bit() {
    let d = scratch("render");
    let run = d.join("run");
    ok_json(&tiny(&run, 1000, &[]));
    let run_s = run.to_str().unwrap();
    let eval = ok_json(&mpo(&["eval", "--checkpoint", run_s, "--episodes", "2"]));
    let render = |name: &str| {
        let (gif, png) = (d.join(format!("{name}.gif")), d.join(format!("{name}.png")));
        let s = ok_json(&mpo(&[
            "render",
            "--checkpoint",
            run_s,
            "--episodes",
            "2",
            "--steps",
            "30",
            "--width",
            "64",
            "--height",
            "48",
            "--out",
            gif.to_str().unwrap(),
            "--strip",
            png.to_str().unwrap(),
        ]));
        (s, gif, png)
    };
    let (s, gif, png) = render("a");
    // The same environments, seeds and policy as `mpo eval`: the same returns, bit for bit
    // (JSON numbers print the shortest round trip), whole episodes though 30 steps are shown.
    assert_eq!(s["returns"], eval["returns"]);
    assert_eq!(s["return_mean"], eval["return_mean"]);
    assert_eq!(s["camera"], "fixed");
    // cartpole runs at 100 Hz; a GIF shows every 2nd step at 50 fps: steps 0, 2, ..., 30.
    assert_eq!(s["frame_every"], 2);
    assert_eq!(s["fps"], 50.0);
    assert_eq!(s["frames"], 2 * 16);

    let (w, h, frames, delays) = gif_frames(&gif);
    assert_eq!((w, h), (64, 48));
    assert_eq!(frames.len(), 32);
    assert!(delays.iter().all(|&d| d == 2), "{delays:?}");
    // Each frame shows a different step number and a moving cart; episode 1 starts afresh.
    for pair in frames.windows(2) {
        assert_ne!(pair[0], pair[1]);
    }
    // The sheet: 8 tiles of 64x48 in two rows of 4 under a title line.
    let (sw, sh, sheet) = png_rgb(&png);
    assert_eq!((sw, sh), (4 * 64 + 5 * 4, 8 + 2 * 4 + 2 * 48 + 2 * 4));
    assert!(colours(&sheet) > 50);

    // Again: the same files, byte for byte.
    let (s2, gif2, png2) = render("b");
    assert_eq!(s2["returns"], s["returns"]);
    assert!(std::fs::read(&gif).unwrap() == std::fs::read(&gif2).unwrap());
    assert!(std::fs::read(&png).unwrap() == std::fs::read(&png2).unwrap());
}

#[test]
fn bad_requests_are_named_before_any_work() {
    let d = scratch("render-errors");
    let run = d.join("run");
    ok_json(&tiny(&run, 1000, &[]));
    let run_s = run.to_str().unwrap();
    let file = |name: &str| d.join(name).to_str().unwrap().to_string();
    let fails = |extra: &[&str]| {
        let mut args = vec!["render", "--checkpoint", run_s, "--steps", "4"];
        args.extend_from_slice(extra);
        err_text(&mpo(&args))
    };
    let e = fails(&["--out", &file("x.avi")]);
    assert!(
        e.contains("x.avi") && e.contains(".gif") && e.contains(".mp4"),
        "{e}"
    );
    let e = fails(&["--strip", &file("x.jpg")]);
    assert!(e.contains("x.jpg") && e.contains(".png"), "{e}");
    let e = fails(&["--out", &file("x.gif"), "--camera", "nope"]);
    assert!(e.contains("fixed, lookatcart, free"), "{e}");
    let e = fails(&["--out", &file("x.gif"), "--fps", "100"]);
    assert!(e.contains("at most 50") && e.contains(".mp4"), "{e}");
    let mp4 = d.join("x.mp4");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_mpo"))
        .args(["render", "--checkpoint", run_s, "--steps", "4", "--out"])
        .arg(&mp4)
        .env(mpo_host::video::FFMPEG_VAR, d.join("no-such-ffmpeg"))
        .output()
        .unwrap();
    let e = err_text(&out);
    assert!(
        e.contains("apt-get install ffmpeg") && e.contains(".gif needs nothing"),
        "{e}"
    );
    // Nothing was left behind by the failed requests.
    assert!(!d.join("x.gif").exists() && !mp4.exists());
}

/// `.mp4` through the ffmpeg program. Not skipped when ffmpeg is missing: it fails, naming the
/// package (`.ci/run` installs it), so a pass always means an MP4 was written.
#[test]
fn mp4_through_ffmpeg() {
    let has_ffmpeg = std::process::Command::new("ffmpeg")
        .arg("-version")
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(
        has_ffmpeg,
        "no ffmpeg program on this machine: install Debian's `ffmpeg` (apt-get install ffmpeg; \
         .ci/run does) to test .mp4 output"
    );
    let d = scratch("render-mp4");
    let run = d.join("run");
    ok_json(&tiny(&run, 1000, &[]));
    let mp4 = d.join("a.mp4");
    // Odd sizes are padded to even ones for yuv420p.
    let s = ok_json(&mpo(&[
        "render",
        "--checkpoint",
        run.to_str().unwrap(),
        "--steps",
        "20",
        "--width",
        "65",
        "--height",
        "47",
        "--out",
        mp4.to_str().unwrap(),
    ]));
    assert_eq!(s["fps"], 100.0, "mp4 plays at the control rate");
    assert_eq!(s["frames"], 21);
    let bytes = std::fs::read(&mp4).unwrap();
    assert_eq!(&bytes[4..8], b"ftyp", "an MP4 file");
}

#[test]
fn train_render_every_writes_sheets_and_changes_nothing() {
    let d = scratch("render-train");
    let plain = ok_json(&tiny(&d.join("plain"), 1000, &[]));
    let pictured = d.join("pictured");
    let with = ok_json(&tiny(&pictured, 1000, &["--render-every", "1"]));
    assert_eq!(with["params_sha256"], plain["params_sha256"]);
    assert_eq!(with["eval_return_mean"], plain["eval_return_mean"]);
    // The tiny row evaluates at steps 0 and 1000: a sheet each, 8 tiles of 320x240.
    for step in [0, 1000] {
        let (w, h, _) = png_rgb(&pictured.join(format!("renders/step-{step:09}.png")));
        assert_eq!((w, h), (4 * 320 + 5 * 4, 8 + 2 * 4 + 2 * 240 + 2 * 4));
    }
    let e = err_text(&tiny(&d.join("zero"), 1000, &["--render-every", "0"]));
    assert!(e.contains("--render-every"), "{e}");
}
