//! The two CRC-32s of the log formats written here, bit by bit (the files are small): CRC-32C
//! (Castagnoli) for TFRecord, the IEEE CRC-32 of zlib for W&B's transaction log.

/// Reflected CRC-32 with polynomial `poly` (reflected form), initial value and final XOR all ones.
fn crc32_reflected(poly: u32, data: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in data {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ poly
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// CRC-32C (Castagnoli, reflected polynomial 0x82F63B78).
pub(crate) fn crc32c(data: &[u8]) -> u32 {
    crc32_reflected(0x82F6_3B78, data)
}

/// CRC-32 as zlib's `crc32` (IEEE 802.3, reflected polynomial 0xEDB88320).
pub(crate) fn crc32(data: &[u8]) -> u32 {
    crc32_reflected(0xEDB8_8320, data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_match_their_published_check_values() {
        // "123456789" is the CRC catalogue's check string.
        assert_eq!(crc32c(b"123456789"), 0xE306_9283);
        assert_eq!(crc32c(&[0u8; 32]), 0x8A91_36AA);
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    }
}
