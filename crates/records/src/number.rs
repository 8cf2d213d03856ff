//! JSON numbers read where they stand in a body, correctly rounded to `f64`.
//!
//! The grammar is JSON's, checked while the digits are gathered:
//! `-?(0|[1-9][0-9]*)(.[0-9]+)?([eE][+-]?[0-9]+)?`. The value is the `f64` nearest to the
//! decimal (ties to even), as std's parser gives. Most landmark coordinates take one of two
//! exact shortcuts:
//!
//! - up to 2^53 with a power of ten up to 10^22 (`12.5`, `300`): both operands are exact `f64`s,
//!   so one multiplication or division rounds correctly (Clinger's fast path);
//! - up to 19 digits over 10^k, k ≤ 19 (`319.12345678901234`, what a client computing in doubles
//!   sends): a quotient in floating point is within an ulp or two, and integer arithmetic then
//!   decides exactly which `f64` is nearest, by comparing the decimal with the midpoints either
//!   side (`w · 2^(1-e)` against `(2m ± 1) · 10^k`, both exact in 128 bits).
//!
//! Anything else (more than 19 digits, large exponents, a value at the edge of a binade, the
//! rare case where the quotient was more than an ulp off) goes to fast-float2 on the same text.
//! On the service bench's 17-digit coordinates this takes 256 instructions a number where
//! fast-float2 with JSON's grammar checked around it took 344 (callgrind; docs/PERFORMANCE.md).

/// 10^0 ..= 10^22: every one exact in an `f64`.
const POW10_F64: [f64; 23] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
];

/// 10^0 ..= 10^19, the powers of ten that fit a `u64`.
const POW10_U64: [u64; 20] = {
    let mut t = [1u64; 20];
    let mut i = 1;
    while i < t.len() {
        t[i] = t[i - 1] * 10;
        i += 1;
    }
    t
};

/// Significand bits of an `f64`, the implicit one excluded.
const FRACTION_BITS: u64 = (1 << 52) - 1;

/// Reads the JSON number that starts at byte `start` of `b`: its value (infinite when it is out
/// of the range of `f64`) and the offset just past it, or `None` if no JSON number starts there.
/// It reads the longest number there and stops at the first byte that cannot continue it; what
/// follows is the caller's to check.
///
/// A short number ([`short`]: what detectors and annotations give, `121.0`, `-37.25`) is read
/// in place with no call; anything else by [`general`].
#[inline(always)]
pub(crate) fn read(b: &[u8], start: usize) -> Option<(f64, usize)> {
    match short(b, start) {
        Some(read) => Some(read),
        None => general(b, start),
    }
}

/// The flags (high bit of each byte) of the bytes of `v` that are not ASCII digits: `c + 0x46`
/// reaches 0x80 from 0x3a up, `c - 0x30` wraps below 0x30. Carries and borrows start only at
/// such bytes and move to later ones, so the first flagged byte is the first non-digit.
#[inline(always)]
fn not_digits(v: u64) -> u64 {
    (v.wrapping_add(0x4646_4646_4646_4646) | v.wrapping_sub(0x3030_3030_3030_3030))
        & 0x8080_8080_8080_8080
}

/// The value of the first `n` (1 ..= 7) ASCII digits of `v` (the first in the low byte).
#[inline(always)]
fn first_digits(v: u64, n: usize) -> u64 {
    // The first n bytes (the low ones) moved up, '0's in front: the same n-digit value.
    eight_digits((v << (8 * (8 - n))) | (0x3030_3030_3030_3030 >> (8 * n)))
}

/// The usual number of a landmark list, read without a loop: an optional `-`, one to seven
/// integer digits (no leading zero), optionally `.` and one to fifteen fraction digits (nineteen
/// digits at most), no exponent, with 16 bytes of the body from its first digit on (24 past the
/// point for more than seven fraction digits). Its digits make the same `w` and `q` as
/// [`general`] gathers, and its value is what [`general`]'s shortcuts make of them: `w / 10^f`
/// when `w ≤ 2^53` (the first shortcut's very operation on the same operands; `f ≤ 15`, both
/// exact), else [`nearest`] itself. `None`: not such a number, or the shortcuts cannot tell;
/// [`general`] reads it.
#[inline(always)]
pub(crate) fn short(b: &[u8], start: usize) -> Option<(f64, usize)> {
    let negative = *b.get(start)? == b'-';
    let s = start + usize::from(negative);
    let window: &[u8; 16] = b.get(s..s + 16)?.try_into().ok()?;
    let head = u64::from_le_bytes(window[..8].try_into().ok()?);
    let n = (not_digits(head).trailing_zeros() / 8) as usize;
    if n == 0 || n == 8 || (n > 1 && window[0] == b'0') {
        return None;
    }
    let (w, f) = if window[n] == b'.' {
        let tail = u64::from_le_bytes(window[n + 1..n + 9].try_into().ok()?);
        match (not_digits(tail).trailing_zeros() / 8) as usize {
            0 => return None,
            // The integer digits, then the bytes after the point: the digits without the
            // point, seven at most, read at once.
            f if n + f < 8 => {
                let next = u64::from_le_bytes(window[1..9].try_into().ok()?);
                let low = (1 << (8 * n)) - 1;
                (first_digits((head & low) | (next & !low), n + f), f)
            }
            f @ 1..=7 => (
                first_digits(head, n) * POW10_U64[f] + first_digits(tail, f),
                f,
            ),
            _ => long_fraction(b, s + n + 9, first_digits(head, n), tail, n)?,
        }
    } else {
        (first_digits(head, n), 0)
    };
    let end = s + n + usize::from(f > 0) + f;
    if b.get(end).is_some_and(|&c| c | 0x20 == b'e') {
        return None;
    }
    let v = if w <= 1 << 53 {
        // Exact: w < 2^53.
        (w as i64) as f64 / POW10_F64[f]
    } else {
        far(w, -(f as i64))?
    };
    Some((if negative { -v } else { v }, end))
}

/// `w` (`n` ≤ 7 integer digits) and the first eight fraction digits `tail` of [`short`]'s
/// number, with the fraction digits from `at` on: `w` and the count of fraction digits, when
/// there are at most fifteen and nineteen digits in all.
#[inline(always)]
fn long_fraction(b: &[u8], at: usize, w: u64, tail: u64, n: usize) -> Option<(u64, usize)> {
    let more = u64::from_le_bytes(b.get(at..at + 8)?.try_into().ok()?);
    let f = (not_digits(more).trailing_zeros() / 8) as usize;
    if f == 8 || n + 8 + f > 19 {
        return None;
    }
    // At most 15 digits, then at most 19: within a `u64`.
    let w = w * 100_000_000 + eight_digits(tail);
    let w = if f > 0 {
        w * POW10_U64[f] + first_digits(more, f)
    } else {
        w
    };
    Some((w, 8 + f))
}

/// [`nearest`] out of line, for [`short`]'s numbers of more than 2^53.
#[inline(never)]
fn far(w: u64, q: i64) -> Option<f64> {
    nearest(w, q)
}

/// [`read`] for any number.
#[inline(never)]
pub(crate) fn general(b: &[u8], start: usize) -> Option<(f64, usize)> {
    let negative = b.get(start) == Some(&b'-');
    let mut i = start + usize::from(negative);
    let int_start = i;
    let (mut w, int_digits) = digits(b, i, 0);
    i += int_digits;
    if int_digits == 0 || (int_digits > 1 && b[int_start] == b'0') {
        return None;
    }
    let mut frac_digits = 0;
    if b.get(i) == Some(&b'.') {
        i += 1;
        (w, frac_digits) = digits(b, i, w);
        if frac_digits == 0 {
            return None;
        }
        i += frac_digits;
    }
    let mut exponent: i64 = 0;
    if let Some(b'e' | b'E') = b.get(i) {
        i += 1;
        let negative_exponent = b.get(i) == Some(&b'-');
        i += usize::from(matches!(b.get(i), Some(b'-' | b'+')));
        let exp_start = i;
        while let Some(d) = b.get(i).and_then(|c| decimal(*c)) {
            // Beyond this the value is 0 or infinite either way; the slow path says which.
            if exponent < 100_000 {
                exponent = exponent * 10 + i64::from(d);
            }
            i += 1;
        }
        if i == exp_start {
            return None;
        }
        if negative_exponent {
            exponent = -exponent;
        }
    }
    // Up to 19 digits `w` is exact (10^19 < 2^64); beyond, it has wrapped and is not used.
    let shortcut = if int_digits + frac_digits <= 19 {
        nearest(w, exponent - frac_digits as i64)
    } else {
        None
    };
    let magnitude = match shortcut {
        Some(v) => v,
        None => slow(&b[int_start..i])?,
    };
    Some((if negative { -magnitude } else { magnitude }, i))
}

/// The value of `text` (JSON's grammar, a subset of fast-float2's) when no shortcut applies.
#[cold]
#[inline(never)]
fn slow(text: &[u8]) -> Option<f64> {
    fast_float2::parse(text).ok()
}

/// The value of the decimal digit `c`, if it is one.
#[inline]
fn decimal(c: u8) -> Option<u8> {
    let d = c.wrapping_sub(b'0');
    (d <= 9).then_some(d)
}

/// Reads the run of decimal digits at `i` onto `w` (`w · 10^n + digits`, wrapping): the new `w`
/// and the number of digits `n`. Eight bytes at a time where the body has eight left.
#[inline]
fn digits(b: &[u8], mut i: usize, mut w: u64) -> (u64, usize) {
    let start = i;
    while let Some(chunk) = b.get(i..i + 8) {
        let v = u64::from_le_bytes(chunk.try_into().expect("eight bytes"));
        let not_digit = not_digits(v);
        if not_digit == 0 {
            w = w.wrapping_mul(100_000_000).wrapping_add(eight_digits(v));
            i += 8;
            continue;
        }
        let n = (not_digit.trailing_zeros() / 8) as usize;
        if n > 0 {
            w = w
                .wrapping_mul(POW10_U64[n])
                .wrapping_add(first_digits(v, n));
        }
        return (w, i + n - start);
    }
    while let Some(d) = b.get(i).and_then(|c| decimal(*c)) {
        w = w.wrapping_mul(10).wrapping_add(u64::from(d));
        i += 1;
    }
    (w, i - start)
}

/// The value of eight ASCII digits, the first in the low byte of `v`.
#[inline(always)]
fn eight_digits(v: u64) -> u64 {
    let v = v - 0x3030_3030_3030_3030;
    // Pairs, then quadruples, then the whole (the multipliers put 10^k at each lane).
    let v = v * 10 + (v >> 8);
    let lo = (v & 0x0000_00ff_0000_00ff).wrapping_mul(100 + (1_000_000 << 32));
    let hi = ((v >> 16) & 0x0000_00ff_0000_00ff).wrapping_mul(1 + (10_000 << 32));
    u64::from((lo.wrapping_add(hi) >> 32) as u32)
}

/// The `f64` nearest to `w · 10^q` (ties to even), or `None` when the shortcuts cannot tell.
#[inline]
fn nearest(w: u64, q: i64) -> Option<f64> {
    if w == 0 {
        return Some(0.0);
    }
    if w <= 1 << 53 && (-22..=22).contains(&q) {
        let f = w as f64;
        return Some(if q < 0 {
            f / POW10_F64[q.unsigned_abs() as usize]
        } else {
            f * POW10_F64[q as usize]
        });
    }
    if !(-19..=0).contains(&q) {
        return None;
    }
    let k = q.unsigned_abs() as usize;
    let approx = w as f64 / POW10_F64[k];
    // approx = m · 2^e, m of 53 bits.
    let bits = approx.to_bits();
    let m = (bits & FRACTION_BITS) | (1 << 52);
    let e = (bits >> 52) as i64 - 1075;
    let shift = 1 - e;
    // The value is w / 10^k; against the midpoint (2m + 1) · 2^(e-1) it compares as
    // w · 2^(1-e) against (2m + 1) · 10^k, which needs w · 2^(1-e) < 2^128 and e ≤ 0.
    if e > 0 || shift + i64::from(64 - w.leading_zeros()) > 127 {
        return None;
    }
    // At the bottom of a binade the float below is half an ulp away, not one: the midpoints
    // below are not (2m - 1) · 2^(e-1). Left to the slow path (one value in 2^52).
    if m == 1 << 52 {
        return None;
    }
    let scaled = u128::from(w) << shift;
    let ten_k = u128::from(POW10_U64[k]);
    let midpoint_above = |m: u64| (2 * u128::from(m) + 1) * ten_k;
    let (above, below) = (midpoint_above(m), midpoint_above(m - 1));
    let m = if scaled > above {
        // Nearer m + 1, if not past its own upper midpoint or into the next binade.
        if m + 1 == 1 << 53 || scaled >= midpoint_above(m + 1) {
            return None;
        }
        m + 1
    } else if scaled < below {
        if m - 1 == 1 << 52 || scaled <= midpoint_above(m - 2) {
            return None;
        }
        m - 1
    } else if scaled == above && m & 1 == 1 {
        // A tie between m and m + 1: the even one.
        if m + 1 == 1 << 53 {
            return None;
        }
        m + 1
    } else if scaled == below && m & 1 == 1 {
        m - 1
    } else {
        m
    };
    Some(f64::from_bits(
        (bits & !FRACTION_BITS) | (m & FRACTION_BITS),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// What `read` makes of `text` followed by `tail` (which moves the eight-byte reads).
    fn read_in(text: &str, tail: &str) -> Option<(u64, usize)> {
        let body = format!("{text}{tail}");
        read(body.as_bytes(), 0).map(|(v, end)| (v.to_bits(), end))
    }

    /// `text` reads as std reads it, whether the body ends with it or goes on.
    fn agrees_with_std(text: &str) -> std::result::Result<(), TestCaseError> {
        let want = text.parse::<f64>().unwrap().to_bits();
        for tail in ["", "]", ", 123456789.5]", "e"] {
            if tail == "e" && text.contains(['e', 'E']) {
                continue;
            }
            let got = read_in(text, tail);
            if tail == "e" {
                // "1.5e" is not a number: the exponent has no digits.
                prop_assert_eq!(got, None, "{}{}", text, tail);
            } else {
                prop_assert_eq!(got, Some((want, text.len())), "{}{}", text, tail);
            }
        }
        Ok(())
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(3000))]

        #[test]
        fn any_double_reads_back(bits in any::<u64>(), digits in 0usize..22) {
            let v = f64::from_bits(bits);
            prop_assume!(v.is_finite());
            for text in [format!("{v:?}"), format!("{v:e}"), format!("{v:.digits$e}")] {
                agrees_with_std(&text)?;
            }
        }

        #[test]
        fn pixel_coordinates_read_as_std_reads_them(v in -5000.0f64..5000.0, digits in 0usize..20) {
            agrees_with_std(&format!("{v}"))?;
            agrees_with_std(&format!("{v:.digits$}"))?;
            agrees_with_std(&format!("{:?}", v / 5000.0))?;
        }

        /// The exact midpoints between neighbouring doubles of 2^(52-s) ..= 2^(53-s), where the
        /// rounding direction is decided by ties-to-even alone.
        #[test]
        fn midpoints_round_to_even(s in 0u32..12, base in any::<u64>(), odd in any::<u64>()) {
            let base = (1u64 << (52 - s)) + base % (1u64 << (52 - s));
            let units = 2 * (odd % (1 << s)) + 1; // odd multiples of 2^-(s+1)
            let decimals = (u128::from(units) * 10u128.pow(s + 1)) >> (s + 1);
            let text = format!("{base}.{decimals:0>w$}", w = (s + 1) as usize);
            agrees_with_std(&text)?;
            agrees_with_std(&format!("-{text}"))?;
        }

        /// Decimals a few units of their last digit from a power of two, where the double below
        /// is half as far as the one above.
        #[test]
        fn values_at_the_edge_of_a_binade(j in 0u32..30, k in 10u32..=18, d in -3000i128..3000) {
            // 2^j · 10^k within 19 digits.
            let j = j % ((f64::from(19 - k) * std::f64::consts::LOG2_10) as u32 + 1);
            let scale = 10u128.pow(k);
            let w = ((1u128 << j) * scale) as i128 + d;
            prop_assume!(w > 0 && w < 10i128.pow(19));
            let (int, frac) = (w as u128 / scale, w as u128 % scale);
            agrees_with_std(&format!("{int}.{frac:0>k$}", k = k as usize))?;
        }
    }

    /// Bit patterns of `general`'s answer, to compare answers with `==` (NaN never comes out).
    fn bits(r: Option<(f64, usize)>) -> Option<(u64, usize)> {
        r.map(|(v, end)| (v.to_bits(), end))
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(5000))]

        /// Whatever the text, the fast path either declines or answers as the general reader
        /// does, bit for bit and to the same offset; so `read` is `general`.
        #[test]
        fn the_short_path_answers_as_the_general_reader(
            text in "-?[0-9]{0,9}(\\.[0-9]{0,18})?([eE][+-]?[0-9]{0,3})?",
            tail in "[],} \n\t0-9eE.+x-]{0,30}",
            lead in "[ ,\\[]{0,2}",
        ) {
            let body = format!("{lead}{text}{tail}");
            let b = body.as_bytes();
            for start in 0..=b.len() {
                let want = bits(general(b, start));
                if let Some(got) = short(b, start) {
                    prop_assert_eq!(Some(got).map(|(v, e)| (v.to_bits(), e)), want, "{:?} at {}", body, start);
                    // What `read_short_number` promises its callers.
                    prop_assert!(got.0.is_finite() && got.1 - start <= 24, "{:?} at {}", body, start);
                }
                prop_assert_eq!(bits(read(b, start)), want, "{:?} at {}", body, start);
            }
        }

        /// The numbers it is for take it: up to seven digits either side of the point, or an
        /// integer, with the rest of a landmark list after them.
        #[test]
        fn usual_coordinates_take_the_short_path(
            text in "-?(0|[1-9][0-9]{0,6})(\\.[0-9]{1,7})?",
            tail in "(\\]|,|\\],\\[|, |\\]\\]\\}|\\],\\n)",
        ) {
            let body = format!("{text}{tail}0123456789abcdef");
            let got = short(body.as_bytes(), 0);
            prop_assert!(got.is_some(), "{:?}", body);
            prop_assert_eq!(bits(got), bits(general(body.as_bytes(), 0)));
            prop_assert_eq!(got.map(|(_, e)| e), Some(text.len()));
            prop_assert_eq!(got.map(|(v, _)| v.to_bits()), Some(text.parse::<f64>().unwrap().to_bits()));
        }

        /// Coordinates computed in doubles (up to 17 significant digits) take it too, unless
        /// the shortcuts cannot tell, and read as std reads them.
        #[test]
        fn long_fractions_read_as_std_reads_them(
            v in -5000.0f64..5000.0,
            tail in "(\\]|,|\\],\\[)",
        ) {
            let text = format!("{v}");
            let body = format!("{text}{tail}0123456789abcdef01234567");
            let want = Some((v.to_bits(), text.len()));
            if let Some(got) = short(body.as_bytes(), 0) {
                prop_assert_eq!(Some((got.0.to_bits(), got.1)), want);
            }
            prop_assert_eq!(bits(read(body.as_bytes(), 0)), want);
        }
    }

    #[test]
    fn the_grammar_is_json() {
        for (text, value, len) in [
            ("0", 0.0, 1),
            ("-0", -0.0, 2),
            ("1E5", 1e5, 3),
            ("1.5e+3", 1500.0, 6),
            ("2.5e-3", 2.5e-3, 6),
            ("0.1]", 0.1, 3),
            ("12x", 12.0, 2),
            ("0x10", 0.0, 1),
            ("1e400", f64::INFINITY, 5),
            ("-1e400", f64::NEG_INFINITY, 6),
            ("1e-400", 0.0, 6),
            ("1e99999999999999999999", f64::INFINITY, 22),
            ("123456789012345678901234567890", 1.2345678901234568e29, 30),
            ("0.000000000000000000001234", 1.234e-21, 26),
        ] {
            assert_eq!(read_in(text, ""), Some((value.to_bits(), len)), "{text}");
        }
        for text in [
            "", "-", "01", "-01.5", "00", "1.", "1.e5", ".5", "+1", "1e", "1e+", "-e1", "nan",
            "inf", "Infinity", " 1",
        ] {
            assert_eq!(read_in(text, ""), None, "{text:?}");
            assert_eq!(read_in(text, ", 12345678]"), None, "{text:?} then more");
        }
    }

    #[test]
    fn eight_digits_at_a_time() {
        for text in ["12345678", "00000000", "99999999", "10203040"] {
            let v = u64::from_le_bytes(text.as_bytes().try_into().unwrap());
            assert_eq!(eight_digits(v), text.parse::<u64>().unwrap());
        }
        // Runs of every length, then a byte of each kind that ends them.
        for n in 0..20 {
            let run: String = "9876543210987654321".chars().take(n).collect();
            for end in ["", ".", "/", ":", "e", " ", "\u{ff}", "00000000"] {
                let body = format!("{run}{end}");
                let (w, len) = digits(body.as_bytes(), 0, 0);
                let want = if end == "00000000" { n + 8 } else { n };
                assert_eq!(len, want, "{body:?}");
                if want <= 19 {
                    let text = &body[..want];
                    assert_eq!(w, text.parse::<u64>().unwrap_or(0), "{body:?}");
                }
            }
        }
    }
}
