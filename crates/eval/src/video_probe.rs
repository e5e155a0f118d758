//! Reading back an H.264 MP4 ([`crate::video`]'s, or any single-track one with `stco` chunk
//! offsets): the boxes `moov/trak/mdia/minf/stbl` give the samples (`stsz`, `stsc`, `stco`)
//! and the decoder set-up (`stsd/avc1/avcC`: SPS and PPS); each sample's length-prefixed NAL
//! units are handed to OpenH264's decoder as Annex B. [`probe`] returns what was decoded: the
//! frame count, the size and the first frame, so a test or a user can check a video plays
//! without a system player.

use crate::EvalError;
use openh264::decoder::Decoder;
use openh264::formats::YUVSource;
use std::path::Path;

/// What a video decoded to.
#[derive(Clone, Debug, PartialEq)]
pub struct VideoProbe {
    /// Samples in the track.
    pub samples: usize,
    /// Frames the decoder returned.
    pub decoded: usize,
    /// Width and height the `avc1` entry states.
    pub stated_size: (u32, u32),
    /// Width and height of the decoded frames (of the first; all are checked equal).
    pub decoded_size: (u32, u32),
    /// The first decoded frame as 8-bit RGB.
    pub first_rgb: Vec<u8>,
}

fn bad(path: &Path, m: impl std::fmt::Display) -> EvalError {
    EvalError::Input(format!("{}: not a readable H.264 MP4: {m}", path.display()))
}

/// The payload of the first box of type `name` among the boxes in `data`.
fn find<'a>(data: &'a [u8], name: &[u8; 4]) -> Option<&'a [u8]> {
    let mut i = 0;
    while i + 8 <= data.len() {
        let size = u32::from_be_bytes(data[i..i + 4].try_into().ok()?) as usize;
        if size < 8 || i + size > data.len() {
            return None;
        }
        if &data[i + 4..i + 8] == name {
            return Some(&data[i + 8..i + size]);
        }
        i += size;
    }
    None
}

fn be32(d: &[u8], at: usize) -> Option<u32> {
    Some(u32::from_be_bytes(d.get(at..at + 4)?.try_into().ok()?))
}

/// Decodes the video at `path` (see the module documentation).
pub fn probe(path: &Path) -> Result<VideoProbe, EvalError> {
    let file = dataset::io::read(path)?;
    let e = |m: &str| bad(path, m);
    let mut stbl = find(&file, b"moov").ok_or_else(|| e("no moov box"))?;
    for name in [b"trak", b"mdia", b"minf", b"stbl"] {
        stbl = find(stbl, name).ok_or_else(|| e("no sample table"))?;
    }
    let stsd = find(stbl, b"stsd").ok_or_else(|| e("no stsd"))?;
    let avc1 = find(stsd.get(8..).ok_or_else(|| e("short stsd"))?, b"avc1").ok_or_else(|| e("no avc1 entry (not H.264)"))?;
    let stated_size = (
        u16::from_be_bytes(avc1.get(24..26).ok_or_else(|| e("short avc1"))?.try_into().unwrap_or_default()) as u32,
        u16::from_be_bytes(avc1.get(26..28).ok_or_else(|| e("short avc1"))?.try_into().unwrap_or_default()) as u32,
    );
    let avcc = find(avc1.get(78..).ok_or_else(|| e("short avc1"))?, b"avcC").ok_or_else(|| e("no avcC"))?;
    let mut setup = Vec::new();
    let mut at = 5;
    for _ in 0..2 {
        let count = (*avcc.get(at).ok_or_else(|| e("short avcC"))? & if at == 5 { 31 } else { 255 }) as usize;
        at += 1;
        for _ in 0..count {
            let len = u16::from_be_bytes(avcc.get(at..at + 2).ok_or_else(|| e("short avcC"))?.try_into().unwrap_or_default()) as usize;
            setup.extend_from_slice(&[0, 0, 0, 1]);
            setup.extend_from_slice(avcc.get(at + 2..at + 2 + len).ok_or_else(|| e("short avcC"))?);
            at += 2 + len;
        }
    }
    let stsz = find(stbl, b"stsz").ok_or_else(|| e("no stsz"))?;
    let (fixed, count) = (be32(stsz, 4).ok_or_else(|| e("short stsz"))?, be32(stsz, 8).ok_or_else(|| e("short stsz"))? as usize);
    let sizes: Vec<usize> = (0..count).map(|k| if fixed != 0 { Some(fixed as usize) } else { be32(stsz, 12 + 4 * k).map(|v| v as usize) }).collect::<Option<_>>().ok_or_else(|| e("short stsz"))?;
    let stco = find(stbl, b"stco").ok_or_else(|| e("no stco"))?;
    let chunks: Vec<usize> = (0..be32(stco, 4).ok_or_else(|| e("short stco"))? as usize).map(|k| be32(stco, 8 + 4 * k).map(|v| v as usize)).collect::<Option<_>>().ok_or_else(|| e("short stco"))?;
    let stsc = find(stbl, b"stsc").ok_or_else(|| e("no stsc"))?;
    let runs: Vec<(usize, usize)> = (0..be32(stsc, 4).ok_or_else(|| e("short stsc"))? as usize)
        .map(|k| Some((be32(stsc, 8 + 12 * k)? as usize, be32(stsc, 12 + 12 * k)? as usize)))
        .collect::<Option<_>>()
        .ok_or_else(|| e("short stsc"))?;
    let mut decoder = Decoder::new().map_err(|x| bad(path, x))?;
    let (mut decoded, mut decoded_size, mut first_rgb) = (0usize, (0u32, 0u32), Vec::new());
    let mut sample = 0;
    for (c, &offset) in chunks.iter().enumerate() {
        let per_chunk = runs.iter().rev().find(|(first, _)| *first <= c + 1).map_or(0, |r| r.1);
        let mut pos = offset;
        for _ in 0..per_chunk {
            let Some(&size) = sizes.get(sample) else { break };
            let data = file.get(pos..pos + size).ok_or_else(|| e("a sample lies past the end of the file"))?;
            let mut annex_b = if sample == 0 { setup.clone() } else { Vec::new() };
            let mut i = 0;
            while i + 4 <= data.len() {
                let len = be32(data, i).unwrap_or(0) as usize;
                annex_b.extend_from_slice(&[0, 0, 0, 1]);
                annex_b.extend_from_slice(data.get(i + 4..i + 4 + len).ok_or_else(|| e("a NAL unit overruns its sample"))?);
                i += 4 + len;
            }
            if let Some(yuv) = decoder.decode(&annex_b).map_err(|x| bad(path, x))? {
                let (w, h) = yuv.dimensions();
                if decoded == 0 {
                    decoded_size = (w as u32, h as u32);
                    first_rgb = vec![0; w * h * 3];
                    yuv.write_rgb8(&mut first_rgb);
                } else if (w as u32, h as u32) != decoded_size {
                    return Err(e("the frame size changes"));
                }
                decoded += 1;
            }
            pos += size;
            sample += 1;
        }
    }
    decoded += decoder.flush_remaining().map_err(|x| bad(path, x))?.len();
    Ok(VideoProbe { samples: count, decoded, stated_size, decoded_size, first_rgb })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::video::VideoWriter;

    #[test]
    fn a_written_video_decodes_to_its_frames_at_its_size() {
        let dir = tempfile::tempdir().unwrap();
        // An odd width and a height under 16: padded to 32x16.
        let (w, h) = (31u32, 13u32);
        let path = dir.path().join("v.mp4");
        let mut v = VideoWriter::create(&path, w, h, 10.0).unwrap();
        for k in 0..5u32 {
            let rgb: Vec<u8> = (0..w * h).flat_map(|p| [((p % w) * 16) as u8, ((p / w) * 18) as u8, (k * 40) as u8]).collect();
            v.push(&rgb).unwrap();
        }
        assert_eq!(v.finish().unwrap(), 5);
        let p = probe(&path).unwrap();
        assert_eq!((p.samples, p.decoded), (5, 5));
        assert_eq!((p.stated_size, p.decoded_size), ((32, 16), (32, 16)));
        // The first frame comes back close to what went in (lossy, yuv420p: a loose bound).
        let err: f64 = (0..h as usize)
            .flat_map(|y| (0..w as usize).map(move |x| (x, y)))
            .map(|(x, y)| (p.first_rgb[3 * (y * 32 + x)] as f64 - ((x as u32 * 16) as u8) as f64).abs())
            .sum::<f64>()
            / (w * h) as f64;
        assert!(err < 24.0, "mean red error {err}");
        // No temporary left beside it; a video of no frames is refused and leaves nothing.
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        let empty = dir.path().join("empty.mp4");
        assert!(VideoWriter::create(&empty, 4, 4, 10.0).unwrap().finish().is_err());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        assert!(probe(&dir.path().join("missing.mp4")).is_err());
    }
}
