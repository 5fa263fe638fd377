//! PNG encoding, downscaling and contact sheets.

use crate::Frame;

/// An 8-bit RGB image.
#[derive(Debug, Clone, PartialEq)]
pub struct Rgb {
    pub width: u32,
    pub height: u32,
    pub data: Vec<u8>,
}

impl Rgb {
    pub fn from_frame(f: &Frame) -> Rgb {
        Rgb::from_rgba(f.width, f.height, &f.rgba)
    }

    /// From tightly packed RGBA rows (alpha dropped).
    pub fn from_rgba(width: u32, height: u32, rgba: &[u8]) -> Rgb {
        Rgb {
            width,
            height,
            data: rgba
                .chunks_exact(4)
                .flat_map(|p| [p[0], p[1], p[2]])
                .collect(),
        }
    }

    pub fn filled(width: u32, height: u32, color: [u8; 3]) -> Rgb {
        Rgb {
            width,
            height,
            data: color.repeat((width * height) as usize),
        }
    }

    /// Halves the size by averaging 2 × 2 blocks, `times` times.
    pub fn halve(&self, times: u32) -> Rgb {
        let mut img = self.clone();
        for _ in 0..times {
            let (w, h) = (img.width / 2, img.height / 2);
            let mut data = Vec::with_capacity((w * h * 3) as usize);
            for y in 0..h {
                for x in 0..w {
                    for c in 0..3 {
                        let at = |dx: u32, dy: u32| {
                            u32::from(
                                img.data
                                    [(((2 * y + dy) * img.width + 2 * x + dx) * 3 + c) as usize],
                            )
                        };
                        data.push(((at(0, 0) + at(1, 0) + at(0, 1) + at(1, 1) + 2) / 4) as u8);
                    }
                }
            }
            img = Rgb {
                width: w,
                height: h,
                data,
            };
        }
        img
    }

    /// Copies `other` into this image with its top-left corner at (x, y).
    pub fn paste(&mut self, other: &Rgb, x: u32, y: u32) {
        for row in 0..other.height.min(self.height.saturating_sub(y)) {
            let n = other.width.min(self.width.saturating_sub(x)) as usize * 3;
            let src = (row * other.width * 3) as usize;
            let dst = (((y + row) * self.width + x) * 3) as usize;
            self.data[dst..dst + n].copy_from_slice(&other.data[src..src + n]);
        }
    }

    pub fn png(&self) -> Vec<u8> {
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, self.width, self.height);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            enc.set_compression(png::Compression::Fast);
            let mut w = enc.write_header().expect("png header to memory");
            w.write_image_data(&self.data).expect("png data to memory");
        }
        out
    }

    pub fn from_png(bytes: &[u8]) -> Result<Rgb, String> {
        let dec = png::Decoder::new(std::io::Cursor::new(bytes));
        let mut reader = dec.read_info().map_err(|e| e.to_string())?;
        let mut buf = vec![0; reader.output_buffer_size().ok_or("png too large")?];
        let info = reader.next_frame(&mut buf).map_err(|e| e.to_string())?;
        if info.color_type != png::ColorType::Rgb || info.bit_depth != png::BitDepth::Eight {
            return Err(format!(
                "expected 8-bit RGB, got {:?} {:?}",
                info.color_type, info.bit_depth
            ));
        }
        buf.truncate(info.buffer_size());
        Ok(Rgb {
            width: info.width,
            height: info.height,
            data: buf,
        })
    }
}

/// A grid of equally sized images, `columns` wide, with a gutter between them.
pub fn contact_sheet(images: &[Rgb], columns: u32) -> Rgb {
    const GUTTER: u32 = 4;
    let (w, h) = images
        .first()
        .map(|i| (i.width, i.height))
        .unwrap_or((1, 1));
    let rows = (images.len() as u32).div_ceil(columns).max(1);
    let mut sheet = Rgb::filled(
        columns * (w + GUTTER) + GUTTER,
        rows * (h + GUTTER) + GUTTER,
        [255, 255, 255],
    );
    for (i, img) in images.iter().enumerate() {
        let (c, r) = (i as u32 % columns, i as u32 / columns);
        sheet.paste(img, GUTTER + c * (w + GUTTER), GUTTER + r * (h + GUTTER));
    }
    sheet
}

/// Per-channel differences between two images of one size: the mean absolute difference and
/// the share of pixels where some channel differs by more than `threshold`.
pub fn compare(a: &Rgb, b: &Rgb, threshold: u8) -> Result<(f64, f64), String> {
    if (a.width, a.height) != (b.width, b.height) {
        return Err(format!(
            "sizes differ: {}x{} vs {}x{}",
            a.width, a.height, b.width, b.height
        ));
    }
    let total: u64 = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| u64::from(x.abs_diff(*y)))
        .sum();
    let off = a
        .data
        .chunks_exact(3)
        .zip(b.data.chunks_exact(3))
        .filter(|(p, q)| {
            p.iter()
                .zip(q.iter())
                .any(|(x, y)| x.abs_diff(*y) > threshold)
        })
        .count();
    Ok((
        total as f64 / a.data.len() as f64,
        off as f64 / (a.width * a.height) as f64,
    ))
}
