//! The binary glTF container (GLB): a 12-byte header, a JSON chunk, an optional BIN chunk.
//! Parsed here with every length checked (the `gltf` crate's parser underflows on a header
//! length below 12).

/// The chunks of a GLB file, borrowed from the input.
#[derive(Debug)]
pub(crate) struct Glb<'a> {
    /// The JSON chunk.
    pub json: &'a [u8],
    /// The BIN chunk, if present.
    pub bin: Option<&'a [u8]>,
}

const CHUNK_JSON: u32 = 0x4E4F_534A; // "JSON"
const CHUNK_BIN: u32 = 0x004E_4942; // "BIN\0"

fn read_u32(bytes: &[u8], at: usize) -> Option<u32> {
    let b = bytes.get(at..at.checked_add(4)?)?;
    Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

/// Whether `bytes` starts with the GLB magic.
pub(crate) fn is_glb(bytes: &[u8]) -> bool {
    bytes.starts_with(b"glTF")
}

/// Splits a GLB file into its JSON and BIN chunks.
pub(crate) fn parse(bytes: &[u8]) -> Result<Glb<'_>, String> {
    let version = read_u32(bytes, 4).ok_or("truncated GLB: header shorter than 12 bytes")?;
    let length = read_u32(bytes, 8).ok_or("truncated GLB: header shorter than 12 bytes")? as usize;
    if version != 2 {
        return Err(format!("unsupported GLB container version {version} (expected 2)"));
    }
    if length < 12 {
        return Err(format!("invalid GLB: header length {length} is below the 12-byte header"));
    }
    let data = bytes
        .get(..length)
        .ok_or_else(|| format!("truncated GLB: header says {length} bytes, file has {}", bytes.len()))?;
    let mut at = 12usize;
    let mut json = None;
    let mut bin = None;
    let mut index = 0usize;
    while at < data.len() {
        let chunk_len = read_u32(data, at).ok_or_else(|| format!("truncated GLB: chunk {index} header at byte {at}"))?;
        let chunk_type =
            read_u32(data, at + 4).ok_or_else(|| format!("truncated GLB: chunk {index} header at byte {at}"))?;
        let start = at + 8;
        let end = start
            .checked_add(chunk_len as usize)
            .filter(|&end| end <= data.len())
            .ok_or_else(|| {
                format!("truncated GLB: chunk {index} claims {chunk_len} bytes, {} remain", data.len().saturating_sub(start))
            })?;
        let payload = &data[start..end];
        match (index, chunk_type) {
            (0, CHUNK_JSON) => json = Some(payload),
            (0, other) => return Err(format!("invalid GLB: first chunk has type 0x{other:08x}, expected JSON")),
            (_, CHUNK_BIN) if bin.is_none() => bin = Some(payload),
            (_, CHUNK_BIN) => return Err("invalid GLB: more than one BIN chunk".to_string()),
            (_, CHUNK_JSON) => return Err("invalid GLB: more than one JSON chunk".to_string()),
            _ => {} // unknown chunk types are skipped, as the spec requires
        }
        // Chunks are 4-byte aligned.
        at = end.checked_add(3).map(|e| e & !3).unwrap_or(usize::MAX);
        index += 1;
    }
    let json = json.ok_or("invalid GLB: no JSON chunk")?;
    Ok(Glb { json, bin })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn glb(json: &[u8], bin: Option<&[u8]>) -> Vec<u8> {
        let pad = |v: &mut Vec<u8>, fill: u8| {
            while !v.len().is_multiple_of(4) {
                v.push(fill);
            }
        };
        let mut j = json.to_vec();
        pad(&mut j, b' ');
        let mut out = Vec::new();
        out.extend_from_slice(b"glTF");
        out.extend_from_slice(&2u32.to_le_bytes());
        out.extend_from_slice(&0u32.to_le_bytes());
        out.extend_from_slice(&(j.len() as u32).to_le_bytes());
        out.extend_from_slice(&CHUNK_JSON.to_le_bytes());
        out.extend_from_slice(&j);
        if let Some(b) = bin {
            let mut b = b.to_vec();
            pad(&mut b, 0);
            out.extend_from_slice(&(b.len() as u32).to_le_bytes());
            out.extend_from_slice(&CHUNK_BIN.to_le_bytes());
            out.extend_from_slice(&b);
        }
        let n = out.len() as u32;
        out[8..12].copy_from_slice(&n.to_le_bytes());
        out
    }

    #[test]
    fn parses_json_and_bin() {
        let file = glb(b"{}", Some(&[1, 2, 3]));
        let g = parse(&file).unwrap();
        assert_eq!(g.json, b"{}  ");
        assert_eq!(g.bin, Some(&[1u8, 2, 3, 0][..]));
    }

    #[test]
    fn every_truncation_is_an_error_not_a_panic() {
        let file = glb(br#"{"asset":{"version":"2.0"}}"#, Some(&[9; 16]));
        for n in 0..file.len() {
            let mut cut = file[..n].to_vec();
            if cut.len() >= 4 {
                assert!(parse(&cut).is_err(), "prefix of {n} bytes accepted");
            }
            // Also with the header length patched to the truncated size.
            if cut.len() >= 12 {
                let len = cut.len() as u32;
                cut[8..12].copy_from_slice(&len.to_le_bytes());
                let _ = parse(&cut);
            }
        }
        let mut bad = file.clone();
        bad[8..12].copy_from_slice(&3u32.to_le_bytes());
        assert!(parse(&bad).unwrap_err().contains("below"));
    }
}
