//! Episode videos: MP4 (H.264) through `ffmpeg` when it is on the PATH, else an animated GIF
//! encoded here. Either way one file, looping GIF or faststart MP4, that a browser plays.

use std::io::Write;
use std::process::{Command, Stdio};

use crate::image::Rgb;

/// An encoded video and its file extension (`mp4` or `gif`).
pub struct Video {
    pub bytes: Vec<u8>,
    pub extension: &'static str,
    /// What encoded it, for the logs and the report.
    pub encoder: String,
}

/// Encodes `frames` (all the same size) at `fps`: MP4 through ffmpeg if it is installed and
/// works, an animated GIF otherwise. `Err` only when both fail.
pub fn encode(frames: &[Rgb], fps: u32) -> Result<Video, String> {
    let Some(first) = frames.first() else {
        return Err("a video needs at least one frame".into());
    };
    if frames
        .iter()
        .any(|f| (f.width, f.height) != (first.width, first.height))
    {
        return Err("video frames differ in size".into());
    }
    if ffmpeg_available() {
        match mp4(frames, fps) {
            Ok(bytes) => {
                return Ok(Video {
                    bytes,
                    extension: "mp4",
                    encoder: "ffmpeg libx264".into(),
                });
            }
            Err(e) => tracing::warn!(error = %e, "ffmpeg failed; writing a GIF instead"),
        }
    }
    Ok(Video {
        bytes: gif(frames, fps)?,
        extension: "gif",
        encoder: "gif (NeuQuant palette per frame)".into(),
    })
}

/// Whether `ffmpeg` runs (checked once per process).
pub fn ffmpeg_available() -> bool {
    static FOUND: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *FOUND.get_or_init(|| {
        Command::new("ffmpeg")
            .arg("-version")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .is_ok_and(|s| s.success())
    })
}

/// Animated GIF, looping, `fps` frames per second (GIF delays are in hundredths of a second).
pub fn gif(frames: &[Rgb], fps: u32) -> Result<Vec<u8>, String> {
    let first = &frames[0];
    let (w, h) = (
        u16::try_from(first.width).map_err(|_| "GIF frames are at most 65535 wide")?,
        u16::try_from(first.height).map_err(|_| "GIF frames are at most 65535 high")?,
    );
    let mut out = Vec::new();
    {
        let mut enc = gif::Encoder::new(&mut out, w, h, &[]).map_err(|e| e.to_string())?;
        enc.set_repeat(gif::Repeat::Infinite)
            .map_err(|e| e.to_string())?;
        let delay = (100 / fps.max(1)).max(2) as u16;
        for f in frames {
            // Speed 10 of 1..=30: a good palette for smooth shading at a few ms a frame.
            let mut frame = gif::Frame::from_rgb_speed(w, h, &f.data, 10);
            frame.delay = delay;
            enc.write_frame(&frame).map_err(|e| e.to_string())?;
        }
    }
    Ok(out)
}

/// ffmpeg reading `width` × `height` RGB frames at `fps` on its stdin and writing a faststart
/// H.264 (yuv420p) MP4 to `path`, with `extra` encoder arguments.
fn h264(
    path: &std::path::Path,
    width: u32,
    height: u32,
    fps: u32,
    extra: &[&str],
) -> Result<std::process::Child, String> {
    Command::new("ffmpeg")
        .args(["-hide_banner", "-loglevel", "error", "-y", "-f", "rawvideo"])
        .args(["-pix_fmt", "rgb24", "-s"])
        .arg(format!("{width}x{height}"))
        .args(["-r", &fps.to_string(), "-i", "-"])
        .args(extra)
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
        .map_err(|e| format!("starting ffmpeg: {e}"))
}

/// H.264 MP4 from raw RGB on ffmpeg's stdin, through a temporary file (MP4 needs a seekable
/// output for its index).
fn mp4(frames: &[Rgb], fps: u32) -> Result<Vec<u8>, String> {
    let first = &frames[0];
    let dir = std::env::temp_dir().join(format!(
        "assay-video-{}-{:?}",
        std::process::id(),
        std::thread::current().id()
    ));
    std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
    let path = dir.join("episode.mp4");
    // H.264 in yuv420p needs even sizes: pad by one pixel where needed.
    let mut child = h264(
        &path,
        first.width,
        first.height,
        fps,
        &["-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2"],
    )?;
    let written = {
        let mut stdin = child.stdin.take().expect("piped stdin");
        frames.iter().try_for_each(|f| stdin.write_all(&f.data))
    };
    let out = child.wait_with_output().map_err(|e| e.to_string())?;
    let result = match (written, out.status.success()) {
        (Ok(()), true) => std::fs::read(&path).map_err(|e| e.to_string()),
        (_, _) => Err(format!(
            "ffmpeg {}: {}",
            out.status,
            String::from_utf8_lossy(&out.stderr).trim()
        )),
    };
    let _ = std::fs::remove_dir_all(&dir);
    result
}

/// An H.264 MP4 that ffmpeg writes as frames arrive: many episodes back to back in one file,
/// as datasets keep them (LeRobotDataset). Constant frame rate, yuv420p, a keyframe every other
/// frame and no B-frames, so that a reader seeking to any frame's timestamp decodes it at once.
pub struct Mp4Writer {
    child: Option<std::process::Child>,
    stdin: Option<std::process::ChildStdin>,
    frame_bytes: usize,
    frames: u64,
}

impl Mp4Writer {
    /// Starts ffmpeg writing `path`, frames `width` × `height` (both even) at `fps`.
    pub fn create(
        path: &std::path::Path,
        width: u32,
        height: u32,
        fps: u32,
    ) -> Result<Self, String> {
        if width % 2 == 1 || height % 2 == 1 || width == 0 || height == 0 || fps == 0 {
            return Err(format!(
                "H.264 in yuv420p needs even frame sizes and a frame rate: {width}x{height} at \
                 {fps} frames/s"
            ));
        }
        if !ffmpeg_available() {
            return Err("ffmpeg is not installed (apt-get install ffmpeg)".into());
        }
        let mut child = h264(
            path,
            width,
            height,
            fps,
            &["-crf", "18", "-g", "2", "-bf", "0"],
        )?;
        let stdin = child.stdin.take();
        Ok(Self {
            child: Some(child),
            stdin,
            frame_bytes: width as usize * height as usize * 3,
            frames: 0,
        })
    }

    /// Appends one frame: RGB, rows top to bottom.
    pub fn push(&mut self, rgb: &[u8]) -> Result<(), String> {
        if rgb.len() != self.frame_bytes {
            return Err(format!(
                "a frame of {} bytes where the video's frames have {}",
                rgb.len(),
                self.frame_bytes
            ));
        }
        let stdin = self.stdin.as_mut().ok_or("the video is finished")?;
        stdin
            .write_all(rgb)
            .map_err(|e| format!("writing to ffmpeg: {e}"))?;
        self.frames += 1;
        Ok(())
    }

    /// Closes the file; the number of frames it holds.
    pub fn finish(mut self) -> Result<u64, String> {
        drop(self.stdin.take());
        let child = self.child.take().ok_or("the video is finished")?;
        let out = child.wait_with_output().map_err(|e| e.to_string())?;
        if !out.status.success() {
            return Err(format!(
                "ffmpeg {}: {}",
                out.status,
                String::from_utf8_lossy(&out.stderr).trim()
            ));
        }
        Ok(self.frames)
    }
}

impl Drop for Mp4Writer {
    /// A writer dropped unfinished (an error on the way) stops its ffmpeg.
    fn drop(&mut self) {
        if let Some(mut child) = self.child.take() {
            let _ = child.kill();
            let _ = child.wait();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_gif_holds_every_frame_at_the_right_size_and_rate() {
        let frames: Vec<Rgb> = (0..5u8)
            .map(|i| Rgb::filled(40, 30, [i * 50, 100, 200 - i * 40]))
            .collect();
        let bytes = gif(&frames, 10).unwrap();
        let mut opts = gif::DecodeOptions::new();
        opts.set_color_output(gif::ColorOutput::RGBA);
        let mut dec = opts.read_info(bytes.as_slice()).unwrap();
        assert_eq!((dec.width(), dec.height()), (40, 30));
        let mut n = 0;
        while let Some(f) = dec.read_next_frame().unwrap() {
            assert_eq!(f.delay, 10);
            // The flat colour survives the palette within a step or two.
            let px = &f.buffer[..3];
            let want = [n as u8 * 50, 100, 200 - n as u8 * 40];
            for (a, b) in px.iter().zip(want) {
                assert!(a.abs_diff(b) <= 8, "frame {n}: {px:?} vs {want:?}");
            }
            n += 1;
        }
        assert_eq!(n, 5);
    }

    #[test]
    fn no_frames_is_an_error_not_an_empty_file() {
        assert!(encode(&[], 10).is_err());
    }
}
