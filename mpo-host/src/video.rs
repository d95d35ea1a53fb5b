//! Video files from RGB frames, chosen by the file's extension: `.gif` (built in) and `.mp4`
//! (through the `ffmpeg` program, when the machine has it).
//!
//! GIF: one global palette, computed once from the first frame (NeuQuant, 253 colours, plus
//! exact black and white for the captions and a transparent entry), so colours do not flicker
//! between frames and every frame is a deterministic function of its pixels. Each later frame
//! stores only the rectangle that changed since the previous one, unchanged pixels in it
//! transparent: a fixed camera (cartpole, acrobot) then costs a few hundred bytes a frame. GIF
//! delays are whole hundredths of a second and players slow anything under 2/100 s, so a GIF
//! plays at most 50 frames per second; delays alternate (2, 3, 2, ...) where needed to keep the
//! clock exact.
//!
//! MP4: raw frames piped to `ffmpeg` (H.264, yuv420p, odd sizes padded by a pixel). No C
//! library is linked; without the program (Debian package `ffmpeg`) `.mp4` is an error that
//! says so, and `.gif` needs nothing.

use std::collections::HashMap;
use std::fs::File;
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Stdio};

/// The extensions [`Video::create`] writes.
pub const SUPPORTED: &str = ".gif (built in), .mp4 (needs the ffmpeg program)";

/// The highest frame rate a GIF plays at (a delay of 2/100 s).
pub const GIF_MAX_FPS: f64 = 50.0;

/// Overrides the `ffmpeg` program `.mp4` is written with.
pub const FFMPEG_VAR: &str = "MPO_FFMPEG";

/// Why a video or picture could not be written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum MediaError {
    /// An extension no writer handles.
    #[error("{path}: unsupported file type; supported: {supported}")]
    UnsupportedExtension {
        /// The file.
        path: PathBuf,
        /// What is supported.
        supported: &'static str,
    },
    /// `.mp4` without the `ffmpeg` program.
    #[error(
        "{path}: writing .mp4 needs the `ffmpeg` program, which was not found ({program}): on \
         Debian, `apt-get install ffmpeg`, or set {FFMPEG_VAR} to its path; .gif needs nothing"
    )]
    NoFfmpeg {
        /// The file.
        path: PathBuf,
        /// The program looked for.
        program: String,
    },
    /// `ffmpeg` failed.
    #[error("{path}: ffmpeg failed ({status}): {stderr}")]
    Ffmpeg {
        /// The file.
        path: PathBuf,
        /// Its exit status.
        status: String,
        /// What it printed.
        stderr: String,
    },
    /// A frame rate the format cannot play.
    #[error("{path}: {message}")]
    FrameRate {
        /// The file.
        path: PathBuf,
        /// Why.
        message: String,
    },
    /// Writing failed.
    #[error("cannot write {path}: {message}")]
    Write {
        /// The file.
        path: PathBuf,
        /// Why.
        message: String,
    },
}

/// The container a path asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// Animated GIF.
    Gif,
    /// H.264 in MP4, through ffmpeg.
    Mp4,
}

impl Format {
    /// The format of `path`'s extension (case-insensitive).
    pub fn of(path: &Path) -> Result<Self, MediaError> {
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase());
        match ext.as_deref() {
            Some("gif") => Ok(Self::Gif),
            Some("mp4") => Ok(Self::Mp4),
            _ => Err(MediaError::UnsupportedExtension {
                path: path.into(),
                supported: SUPPORTED,
            }),
        }
    }
}

fn write_err(path: &Path) -> impl Fn(&dyn std::fmt::Display) -> MediaError + '_ {
    move |e| MediaError::Write {
        path: path.into(),
        message: e.to_string(),
    }
}

/// A video being written, one frame at a time.
pub enum Video {
    /// `.gif` (boxed: its palette and frame buffers are most of the enum).
    Gif(Box<GifWriter>),
    /// `.mp4`.
    Mp4(Mp4Writer),
}

impl Video {
    /// Starts `path` for `width` x `height` frames shown `fps` times a second.
    pub fn create(path: &Path, width: u32, height: u32, fps: f64) -> Result<Self, MediaError> {
        Ok(match Format::of(path)? {
            Format::Gif => Self::Gif(Box::new(GifWriter::create(path, width, height, fps)?)),
            Format::Mp4 => Self::Mp4(Mp4Writer::create(path, width, height, fps)?),
        })
    }

    /// Appends a frame: RGB, rows from the top, `width * height * 3` bytes.
    pub fn push(&mut self, rgb: &[u8]) -> Result<(), MediaError> {
        match self {
            Self::Gif(g) => g.push(rgb),
            Self::Mp4(m) => m.push(rgb),
        }
    }

    /// Completes the file.
    pub fn finish(self) -> Result<(), MediaError> {
        match self {
            Self::Gif(g) => g.finish(),
            Self::Mp4(m) => m.finish(),
        }
    }
}

/// Palette entries: NeuQuant's colours, then black, white and the transparent slot.
const QUANT_COLORS: usize = 253;
const BLACK: u8 = 253;
const WHITE: u8 = 254;
const TRANSPARENT: u8 = 255;

/// The global palette and the pixel -> index map.
struct Palette {
    quant: color_quant::NeuQuant,
    /// Colours already looked up (successive frames share most of theirs).
    cache: HashMap<[u8; 3], u8>,
}

impl Palette {
    fn from_frame(rgb: &[u8]) -> Self {
        let rgba: Vec<u8> = rgb
            .chunks_exact(3)
            .flat_map(|p| [p[0], p[1], p[2], 255])
            .collect();
        Self {
            quant: color_quant::NeuQuant::new(10, QUANT_COLORS, &rgba),
            cache: HashMap::new(),
        }
    }

    /// The 256 RGB entries of the GIF's global colour table.
    fn table(&self) -> Vec<u8> {
        let mut t = self.quant.color_map_rgb();
        t.resize(QUANT_COLORS * 3, 0);
        t.extend_from_slice(&[0, 0, 0, 255, 255, 255, 0, 0, 0]);
        t
    }

    fn index(&mut self, p: [u8; 3]) -> u8 {
        match p {
            [0, 0, 0] => BLACK,
            [255, 255, 255] => WHITE,
            _ => *self
                .cache
                .entry(p)
                .or_insert_with(|| self.quant.index_of(&[p[0], p[1], p[2], 255]) as u8),
        }
    }
}

/// The delay of frame `i` in hundredths of a second, so that frame `i` starts at
/// `round(100 i / fps)`.
fn gif_delay(i: u64, fps: f64) -> u16 {
    let at = |n: u64| (100.0 * n as f64 / fps).round() as u64;
    (at(i + 1) - at(i)) as u16
}

/// An animated GIF being written.
pub struct GifWriter {
    path: PathBuf,
    file: Option<BufWriter<File>>,
    encoder: Option<gif::Encoder<BufWriter<File>>>,
    palette: Option<Palette>,
    width: u16,
    height: u16,
    fps: f64,
    frames: u64,
    previous: Vec<u8>,
    current: Vec<u8>,
}

impl GifWriter {
    fn create(path: &Path, width: u32, height: u32, fps: f64) -> Result<Self, MediaError> {
        if !(fps > 0.0 && fps <= GIF_MAX_FPS) {
            return Err(MediaError::FrameRate {
                path: path.into(),
                message: format!(
                    "a GIF plays at most {GIF_MAX_FPS} frames per second (delays are whole \
                     hundredths of a second and players slow anything under 2/100 s); asked \
                     for {fps}: lower --fps, or write .mp4"
                ),
            });
        }
        let (w, h) = (u16::try_from(width), u16::try_from(height));
        let (Ok(width), Ok(height)) = (w, h) else {
            return Err(write_err(path)(&"a GIF is at most 65535 pixels a side"));
        };
        let file = File::create(path).map_err(|e| write_err(path)(&e))?;
        Ok(Self {
            path: path.into(),
            file: Some(BufWriter::new(file)),
            encoder: None,
            palette: None,
            width,
            height,
            fps,
            frames: 0,
            previous: Vec::new(),
            current: Vec::new(),
        })
    }

    fn push(&mut self, rgb: &[u8]) -> Result<(), MediaError> {
        let (w, h) = (self.width as usize, self.height as usize);
        assert_eq!(rgb.len(), w * h * 3, "frame size");
        let err = write_err(&self.path);
        if self.encoder.is_none() {
            let palette = Palette::from_frame(rgb);
            let file = self.file.take().expect("the file until the first frame");
            let mut enc = gif::Encoder::new(file, self.width, self.height, &palette.table())
                .map_err(|e| err(&e))?;
            enc.set_repeat(gif::Repeat::Infinite).map_err(|e| err(&e))?;
            self.encoder = Some(enc);
            self.palette = Some(palette);
        }
        let palette = self.palette.as_mut().expect("set with the encoder");
        self.current.clear();
        self.current.extend(
            rgb.chunks_exact(3)
                .map(|p| palette.index([p[0], p[1], p[2]])),
        );
        let mut frame = self.changed_rect();
        frame.delay = gif_delay(self.frames, self.fps);
        self.encoder
            .as_mut()
            .expect("created above")
            .write_frame(&frame)
            .map_err(|e| err(&e))?;
        std::mem::swap(&mut self.previous, &mut self.current);
        self.frames += 1;
        Ok(())
    }

    /// The current frame as a GIF frame: whole for the first, else the rectangle that differs
    /// from the previous frame, with unchanged pixels transparent (a 1x1 transparent frame
    /// when nothing changed, which still holds the frame's time).
    fn changed_rect(&self) -> gif::Frame<'static> {
        let (w, h) = (self.width as usize, self.height as usize);
        if self.previous.is_empty() {
            return gif::Frame {
                width: self.width,
                height: self.height,
                buffer: self.current.clone().into(),
                ..Default::default()
            };
        }
        let (mut x0, mut y0, mut x1, mut y1) = (w, h, 0, 0);
        for y in 0..h {
            for x in 0..w {
                if self.current[y * w + x] != self.previous[y * w + x] {
                    (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x + 1), y1.max(y + 1));
                }
            }
        }
        if x0 >= x1 {
            (x0, y0, x1, y1) = (0, 0, 1, 1);
        }
        let mut buffer = Vec::with_capacity((x1 - x0) * (y1 - y0));
        for y in y0..y1 {
            for x in x0..x1 {
                let (c, p) = (self.current[y * w + x], self.previous[y * w + x]);
                buffer.push(if c == p { TRANSPARENT } else { c });
            }
        }
        gif::Frame {
            left: x0 as u16,
            top: y0 as u16,
            width: (x1 - x0) as u16,
            height: (y1 - y0) as u16,
            transparent: Some(TRANSPARENT),
            dispose: gif::DisposalMethod::Keep,
            buffer: buffer.into(),
            ..Default::default()
        }
    }

    fn finish(self) -> Result<(), MediaError> {
        let err = write_err(&self.path);
        let mut file = match self.encoder {
            Some(enc) => enc.into_inner().map_err(|e| err(&e))?,
            None => return Err(err(&"no frames")),
        };
        file.flush().map_err(|e| err(&e))
    }
}

/// An MP4 being written by an `ffmpeg` child process.
pub struct Mp4Writer {
    path: PathBuf,
    child: Child,
    stdin: Option<ChildStdin>,
}

impl Mp4Writer {
    fn create(path: &Path, width: u32, height: u32, fps: f64) -> Result<Self, MediaError> {
        if !(fps > 0.0 && fps.is_finite()) {
            return Err(MediaError::FrameRate {
                path: path.into(),
                message: format!("frame rate {fps} must be positive"),
            });
        }
        let program = std::env::var(FFMPEG_VAR).unwrap_or_else(|_| "ffmpeg".into());
        let mut child = Command::new(&program)
            .args(["-y", "-hide_banner", "-loglevel", "error", "-nostdin"])
            .args(["-f", "rawvideo", "-pix_fmt", "rgb24"])
            .args(["-video_size", &format!("{width}x{height}")])
            .args(["-framerate", &format!("{fps}"), "-i", "pipe:0"])
            // yuv420p (what players accept) needs even sides.
            .args(["-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2"])
            .args([
                "-c:v",
                "libx264",
                "-pix_fmt",
                "yuv420p",
                "-movflags",
                "+faststart",
            ])
            .arg(path)
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| match e.kind() {
                std::io::ErrorKind::NotFound | std::io::ErrorKind::PermissionDenied => {
                    MediaError::NoFfmpeg {
                        path: path.into(),
                        program: program.clone(),
                    }
                }
                _ => write_err(path)(&format!("starting {program}: {e}")),
            })?;
        let stdin = child.stdin.take();
        Ok(Self {
            path: path.into(),
            child,
            stdin,
        })
    }

    fn push(&mut self, rgb: &[u8]) -> Result<(), MediaError> {
        let stdin = self.stdin.as_mut().expect("open until finish");
        if stdin.write_all(rgb).is_err() {
            // ffmpeg exited early: its own message says why.
            return Err(self.failure());
        }
        Ok(())
    }

    /// Waits for ffmpeg and reports its status and stderr.
    fn failure(&mut self) -> MediaError {
        self.stdin = None;
        let status = self.child.wait();
        let mut stderr = String::new();
        if let Some(mut s) = self.child.stderr.take() {
            let _ = s.read_to_string(&mut stderr);
        }
        MediaError::Ffmpeg {
            path: self.path.clone(),
            status: status.map_or_else(|e| e.to_string(), |s| s.to_string()),
            stderr: stderr.trim().to_string(),
        }
    }

    fn finish(mut self) -> Result<(), MediaError> {
        drop(self.stdin.take());
        let mut stderr = String::new();
        if let Some(mut s) = self.child.stderr.take() {
            let _ = s.read_to_string(&mut stderr);
        }
        let status = self.child.wait().map_err(|e| write_err(&self.path)(&e))?;
        if status.success() {
            Ok(())
        } else {
            Err(MediaError::Ffmpeg {
                path: self.path.clone(),
                status: status.to_string(),
                stderr: stderr.trim().to_string(),
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn extensions() {
        assert_eq!(Format::of(Path::new("a/b.GIF")).unwrap(), Format::Gif);
        assert_eq!(Format::of(Path::new("b.mp4")).unwrap(), Format::Mp4);
        for bad in ["b.avi", "b", "b.gif.txt"] {
            let e = Format::of(Path::new(bad)).unwrap_err().to_string();
            assert!(
                e.contains(bad) && e.contains(".gif") && e.contains(".mp4"),
                "{e}"
            );
        }
    }

    #[test]
    fn gif_delays_keep_the_clock() {
        // 40 frames per second: 2.5 hundredths a frame, alternating 3 and 2 (round half up
        // at 2.5, 7.5, ...), 100 hundredths per 40 frames.
        let d: Vec<u16> = (0..40).map(|i| gif_delay(i, 40.0)).collect();
        assert_eq!(d.iter().map(|&x| x as u32).sum::<u32>(), 100);
        assert!(d.iter().all(|&x| x == 2 || x == 3), "{d:?}");
        assert!((0..50).all(|i| gif_delay(i, 50.0) == 2));
        assert!((0..25).all(|i| gif_delay(i, 25.0) == 4));
    }
}
