//! How statistics are stored in a checkpoint and in an episodes table, where JSON's own forms
//! are slow or lossy: float64 sums with their infinities and NaN ([`any_f64`]), histograms as
//! the span of bins that count ([`trimmed`]), and reservoirs of float32 values as their bits
//! ([`f32_bits`]). Each also reads the form surgvla wrote before, and refuses what would
//! allocate past its bounds.

/// A float64 in JSON, infinities and NaN included: finite ones as numbers, others as the text
/// `"inf"`, `"-inf"` or `"NaN"` (JSON has no number for them; serde_json writes null).
pub(super) mod any_f64 {
    use serde::{Deserializer, Serializer};

    pub(crate) fn serialize<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
        match *v {
            v if v.is_finite() => s.serialize_f64(v),
            v if v.is_nan() => s.serialize_str("NaN"),
            v if v > 0.0 => s.serialize_str("inf"),
            _ => s.serialize_str("-inf"),
        }
    }

    struct Visitor;

    impl serde::de::Visitor<'_> for Visitor {
        type Value = f64;

        fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.write_str("a number, or \"inf\", \"-inf\" or \"NaN\"")
        }

        fn visit_f64<E>(self, v: f64) -> Result<f64, E> {
            Ok(v)
        }

        fn visit_u64<E>(self, v: u64) -> Result<f64, E> {
            Ok(v as f64)
        }

        fn visit_i64<E>(self, v: i64) -> Result<f64, E> {
            Ok(v as f64)
        }

        fn visit_str<E: serde::de::Error>(self, text: &str) -> Result<f64, E> {
            match text {
                "inf" => Ok(f64::INFINITY),
                "-inf" => Ok(f64::NEG_INFINITY),
                "NaN" => Ok(f64::NAN),
                _ => Err(E::custom(format!("a statistic {text:?}"))),
            }
        }
    }

    pub(crate) fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        d.deserialize_any(Visitor)
    }
}

/// Histograms stored as the span of bins that count: `{"bins": N, "from": first, "counts":
/// "c c c ..."}`, the counts decimal and space-separated (an empty one: `{"bins": N, "from": 0,
/// "counts": ""}`). A plain array of N counts (what surgvla stored before) reads too. A stored histogram is untrusted: more than
/// [`MAX_BINS`] bins, or counts past its end, are refused.
pub(super) mod trimmed {
    use serde::{Deserialize, Deserializer, Serialize, Serializer};
    use std::fmt::Write;

    /// The most bins a stored histogram may declare (ours have 256 or 8,192).
    pub(crate) const MAX_BINS: usize = 1 << 16;

    #[derive(Serialize)]
    struct Span {
        bins: usize,
        from: usize,
        /// The counts as one string of decimal numbers, space-separated: a JSON value of one
        /// node instead of thousands (an episodes table holds one per image feature per
        /// episode, and every pass over its JSON pays per node).
        counts: String,
    }

    /// One stored histogram: a plain array of counts, or a span (read without serde's
    /// buffering of untagged enums: these are the bulk of an episodes table).
    struct Stored(Vec<u64>);

    impl<'de> Deserialize<'de> for Stored {
        fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            d.deserialize_any(StoredVisitor)
        }
    }

    struct StoredVisitor;

    impl<'de> serde::de::Visitor<'de> for StoredVisitor {
        type Value = Stored;

        fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.write_str("a histogram: an array of counts, or {bins, from, counts}")
        }

        /// The counts of a span: decimal numbers, space-separated.
        fn visit_str<E: serde::de::Error>(self, text: &str) -> Result<Stored, E> {
            parse_counts(text).map(Stored).map_err(E::custom)
        }

        fn visit_seq<A: serde::de::SeqAccess<'de>>(self, mut seq: A) -> Result<Stored, A::Error> {
            let mut counts = Vec::with_capacity(seq.size_hint().unwrap_or(0).min(MAX_BINS));
            while let Some(count) = seq.next_element::<u64>()? {
                if counts.len() == MAX_BINS {
                    return Err(serde::de::Error::custom(format!(
                        "a histogram of more than {MAX_BINS} bins"
                    )));
                }
                counts.push(count);
            }
            Ok(Stored(counts))
        }

        fn visit_map<A: serde::de::MapAccess<'de>>(self, mut map: A) -> Result<Stored, A::Error> {
            let (mut bins, mut from, mut counts) = (None, None, None::<Stored>);
            while let Some(key) = map.next_key::<std::borrow::Cow<'de, str>>()? {
                match key.as_ref() {
                    "bins" => bins = Some(map.next_value::<usize>()?),
                    "from" => from = Some(map.next_value::<usize>()?),
                    "counts" => counts = Some(map.next_value::<Stored>()?),
                    _ => {
                        map.next_value::<serde::de::IgnoredAny>()?;
                    }
                }
            }
            let (Some(bins), Some(from), Some(Stored(counts))) = (bins, from, counts) else {
                return Err(serde::de::Error::custom(
                    "a histogram span without bins, from or counts",
                ));
            };
            if bins > MAX_BINS || from.saturating_add(counts.len()) > bins {
                return Err(serde::de::Error::custom(format!(
                    "a histogram of more than {MAX_BINS} bins, or counts past its last bin"
                )));
            }
            let mut full = vec![0; bins];
            full[from..from + counts.len()].copy_from_slice(&counts);
            Ok(Stored(full))
        }
    }

    /// The counts of a span's text (decimal words between ASCII whitespace), at most
    /// [`MAX_BINS`] of them, each read as `u64::from_str` reads it. Words of up to 19 digits
    /// (every count a histogram of ours holds) are read digit by digit; any other word goes to
    /// `from_str`, which decides. An episodes table holds thousands of counts per episode, and
    /// an edit reads every kept episode's.
    pub(crate) fn parse_counts(text: &str) -> Result<Vec<u64>, String> {
        /// Digits that cannot overflow a u64 (10^19 - 1 < 2^64).
        const SAFE_DIGITS: usize = 19;
        let bytes = text.as_bytes();
        // A word and its separator take two bytes at least.
        let mut counts = Vec::with_capacity((bytes.len() / 2 + 1).min(MAX_BINS));
        let mut at = 0;
        while at < bytes.len() {
            if bytes[at].is_ascii_whitespace() {
                at += 1;
                continue;
            }
            if counts.len() == MAX_BINS {
                return Err(format!("a histogram of more than {MAX_BINS} bins"));
            }
            // The commonest word by far (most of a depth histogram's bins are empty).
            if bytes[at] == b'0' && bytes.get(at + 1).is_none_or(u8::is_ascii_whitespace) {
                counts.push(0);
                at += 1;
                continue;
            }
            let start = at;
            let (mut value, mut digits_only) = (0u64, true);
            while let Some(&byte) = bytes.get(at).filter(|b| !b.is_ascii_whitespace()) {
                let digit = byte.wrapping_sub(b'0');
                if digit < 10 && at - start < SAFE_DIGITS {
                    value = value * 10 + u64::from(digit);
                } else {
                    digits_only = false;
                }
                at += 1;
            }
            if digits_only {
                counts.push(value);
            } else {
                // The word ends at ASCII whitespace or the text's end: a char boundary.
                let word = &text[start..at];
                let count = word.parse::<u64>();
                counts.push(count.map_err(|_| format!("a histogram count {word:?}"))?);
            }
        }
        Ok(counts)
    }

    pub(crate) fn serialize<S: Serializer>(
        histograms: &[Vec<u64>],
        s: S,
    ) -> Result<S::Ok, S::Error> {
        let spans: Vec<Span> = histograms
            .iter()
            .map(|h| {
                let from = h.iter().position(|&c| c != 0).unwrap_or(h.len());
                let to = (h.iter().rposition(|&c| c != 0)).map_or(from, |last| last + 1);
                let mut counts = String::with_capacity((to - from) * 4);
                for (i, count) in h[from..to].iter().enumerate() {
                    if i > 0 {
                        counts.push(' ');
                    }
                    // Writing to a String cannot fail.
                    let _ = write!(counts, "{count}");
                }
                Span {
                    bins: h.len(),
                    from: if from == to { 0 } else { from },
                    counts,
                }
            })
            .collect();
        spans.serialize(s)
    }

    pub(crate) fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<Vec<u64>>, D::Error> {
        let stored = Vec::<Stored>::deserialize(d)?;
        Ok(stored.into_iter().map(|Stored(counts)| counts).collect())
    }
}

/// A checkpoint's reservoirs of float32 values: each one string of the values' bits, 8 hex
/// digits a value (written and read several times faster than decimal numbers, and exact for
/// every value, NaN included). A list of numbers (what surgvla wrote before) reads too.
pub(super) mod f32_bits {
    use serde::{Deserializer, Serializer};

    const HEX: &[u8; 16] = b"0123456789abcdef";

    pub(crate) fn serialize<S: Serializer>(
        reservoirs: &[Vec<f32>],
        s: S,
    ) -> Result<S::Ok, S::Error> {
        s.collect_seq(reservoirs.iter().map(|values| {
            let mut text = Vec::with_capacity(values.len() * 8);
            for v in values {
                let bits = v.to_bits();
                text.extend((0..8).rev().map(|k| HEX[(bits >> (4 * k)) as usize & 15]));
            }
            // Hex digits are ASCII.
            String::from_utf8(text).unwrap_or_default()
        }))
    }

    /// One reservoir's values from its hex text.
    pub(crate) fn parse(text: &str) -> Result<Vec<f32>, String> {
        let bytes = text.as_bytes();
        if !bytes.len().is_multiple_of(8) {
            return Err(format!(
                "a reservoir of {} hex digits (not 8 a value)",
                bytes.len()
            ));
        }
        (bytes.chunks_exact(8))
            .map(|digits| {
                let bits = digits.iter().try_fold(0u32, |bits, &d| {
                    Some(bits << 4 | char::from(d).to_digit(16)?)
                });
                bits.map(f32::from_bits).ok_or_else(|| {
                    format!("a reservoir value {:?}", String::from_utf8_lossy(digits))
                })
            })
            .collect()
    }

    /// The most values made room for ahead of a list's reading (a reservoir holds 10,000).
    const HINTED_VALUES: usize = 1 << 14;

    struct Reservoir(Vec<f32>);

    impl<'de> serde::Deserialize<'de> for Reservoir {
        fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            d.deserialize_any(ReservoirVisitor)
        }
    }

    struct ReservoirVisitor;

    impl<'de> serde::de::Visitor<'de> for ReservoirVisitor {
        type Value = Reservoir;

        fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
            f.write_str("a reservoir: float32 bits in hex, or a list of numbers")
        }

        fn visit_str<E: serde::de::Error>(self, text: &str) -> Result<Reservoir, E> {
            parse(text).map(Reservoir).map_err(E::custom)
        }

        fn visit_seq<A: serde::de::SeqAccess<'de>>(
            self,
            mut seq: A,
        ) -> Result<Reservoir, A::Error> {
            let hint = seq.size_hint().unwrap_or(0).min(HINTED_VALUES);
            let mut values = Vec::with_capacity(hint);
            while let Some(v) = seq.next_element::<f32>()? {
                values.push(v);
            }
            Ok(Reservoir(values))
        }
    }

    pub(crate) fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<Vec<f32>>, D::Error> {
        let stored = <Vec<Reservoir> as serde::Deserialize>::deserialize(d)?;
        Ok(stored.into_iter().map(|Reservoir(values)| values).collect())
    }
}

#[cfg(test)]
mod tests {
    use super::trimmed;

    /// A stored count reads as `u64::from_str` reads it: digits, signs, overflow, other bytes
    /// (edge cases and seeded random words).
    #[test]
    fn histogram_counts_read_and_refused_by_their_words() {
        let cases: [(&str, Option<&[u64]>); 14] = [
            ("", Some(&[])),
            ("   ", Some(&[])),
            ("0", Some(&[0])),
            ("+7 00012", Some(&[7, 12])),
            ("1 2\t3\n4\r5\x0c6", Some(&[1, 2, 3, 4, 5, 6])),
            ("18446744073709551615", Some(&[u64::MAX])),
            ("18446744073709551616", None),
            ("-7", None),
            ("1e3", None),
            ("1.0", None),
            ("++7", None),
            ("7+", None),
            ("\u{661}", None),
            ("1 \u{a0}2", None),
        ];
        for (text, expected) in cases {
            let counts = trimmed::parse_counts(text);
            assert_eq!(counts.as_deref().ok(), expected, "{text:?}");
            if let Err(message) = counts {
                let bad = (text.split_ascii_whitespace())
                    .find(|w| w.parse::<u64>().is_err())
                    .expect("a bad word");
                assert!(message.contains(&format!("{bad:?}")), "{message}");
            }
        }
        // Seeded random texts of words a histogram holds and words it does not: 19 and 20
        // digits (the fast path's edge), signs, other bytes, every ASCII space.
        let mut rng = crate::rng::SplitMix64::new(48);
        let pieces = [
            "0", "7", "+", "-", "1", "9", "00", "x", ".", "\u{661}", "\u{a0}", " ", "\t", "\n",
        ];
        for _ in 0..2000 {
            let words = (rng.next_u64() % 6) as usize;
            let mut text = String::new();
            for _ in 0..words {
                match rng.next_u64() % 4 {
                    0 => text.push_str(&(rng.next_u64() >> (rng.next_u64() % 64)).to_string()),
                    1 => text.push_str(&"9".repeat(18 + (rng.next_u64() % 3) as usize)),
                    2 => text.push_str(&format!("{}{}", u64::MAX, rng.next_u64() % 10)),
                    _ => (0..1 + rng.next_u64() % 4).for_each(|_| {
                        text.push_str(pieces[(rng.next_u64() % pieces.len() as u64) as usize])
                    }),
                }
                text.push_str([" ", "\t", "  ", "\r\n"][(rng.next_u64() % 4) as usize]);
            }
            let expected: Result<Vec<u64>, _> = text
                .split_ascii_whitespace()
                .map(str::parse::<u64>)
                .collect();
            assert_eq!(trimmed::parse_counts(&text).ok(), expected.ok(), "{text:?}");
        }
        let too_many = vec!["1"; trimmed::MAX_BINS + 1].join(" ");
        assert!(trimmed::parse_counts(&too_many).is_err());
        assert_eq!(
            trimmed::parse_counts(&too_many[2..]).map(|c| c.len()),
            Ok(trimmed::MAX_BINS)
        );
    }
}
