//! Rows of booleans as hexadecimal text, for the visibility a bundle stores: each row of `n`
//! flags takes `⌈n / 4⌉` digits, point `4k + j` being bit `3 - j` of digit `k` (so the digits
//! read left to right follow the points; a fully visible 68-point row is 17 `f`s). Rows follow
//! each other with no separator; the padding bits of a row's last digit are 0.

/// The text of `rows`, each of `n` flags.
pub fn encode<'a>(rows: impl IntoIterator<Item = &'a [bool]>, n: usize) -> String {
    const DIGITS: &[u8; 16] = b"0123456789abcdef";
    let mut out = String::new();
    for row in rows {
        debug_assert_eq!(row.len(), n);
        for chunk in row.chunks(4) {
            let v = chunk
                .iter()
                .enumerate()
                .fold(0u8, |v, (j, &b)| v | (u8::from(b) << (3 - j)));
            out.push(DIGITS[usize::from(v)] as char);
        }
    }
    out
}

/// The flags of `rows` rows of `n` from `text`, row after row, or what is wrong with it.
pub fn decode(text: &str, n: usize, rows: usize) -> Result<Vec<bool>, String> {
    let per_row = n.div_ceil(4);
    let expected = per_row * rows;
    if text.len() != expected {
        return Err(format!(
            "{} hex digits, expected {expected} ({rows} rows of {n} points, {per_row} digits each)",
            text.len()
        ));
    }
    let mut flags = Vec::with_capacity(n * rows);
    for (r, row) in text.as_bytes().chunks(per_row.max(1)).enumerate() {
        for (k, &c) in row.iter().enumerate() {
            let v = (c as char)
                .to_digit(16)
                .filter(|_| !c.is_ascii_uppercase())
                .ok_or_else(|| {
                    format!("row {r}: {:?} is not a lower-case hex digit", char::from(c))
                })?;
            let points = (n - 4 * k).min(4);
            if v & ((1 << (4 - points)) - 1) != 0 {
                return Err(format!("row {r}: padding bits set in the last digit"));
            }
            flags.extend((0..points).map(|j| v & (1 << (3 - j)) != 0));
        }
    }
    Ok(flags)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn digits_follow_the_points() {
        let row = [
            true, false, false, false, true, true, true, true, false, true,
        ];
        assert_eq!(encode([&row[..]], 10), "8f4");
        assert_eq!(encode([&[true; 68][..]], 68), "f".repeat(17));
    }

    #[test]
    fn bad_text_is_refused_with_the_row() {
        assert!(decode("8f", 10, 1).unwrap_err().contains("expected 3"));
        assert!(decode("8f4g", 10, 1).is_err());
        assert!(decode("8F4", 10, 1).unwrap_err().contains("row 0"));
        // Point 10 does not exist: bit 1 of the last digit is padding.
        assert!(decode("8f48f6", 10, 2).unwrap_err().contains("row 1"));
    }

    fn rows() -> impl Strategy<Value = (usize, usize, Vec<bool>)> {
        (1usize..80, 0usize..6).prop_flat_map(|(n, rows)| {
            (
                Just(n),
                Just(rows),
                prop::collection::vec(any::<bool>(), n * rows),
            )
        })
    }

    proptest! {
        #[test]
        fn decode_inverts_encode((n, rows, flags) in rows()) {
            let text = encode(flags.chunks(n), n);
            prop_assert_eq!(text.len(), n.div_ceil(4) * rows);
            prop_assert_eq!(decode(&text, n, rows).unwrap(), flags);
        }
    }
}
