//! A SunSpec device's register map built from the SunSpec model table: the "SunS" marker at
//! the base, each model's `ID` and `L`, every point the device leaves out holding its type's
//! "not implemented" value, the points given holding theirs, and the end marker. The result is
//! a [`RegisterMap`] like every other library device's.

use super::register_map::{Entry, Raw, RegisterMap, Table};
use rtu2mqtt_profile::sunspec::{self, Point};

/// The register map of a SunSpec device, model by model.
#[derive(Debug, Clone)]
pub struct SunSpecMap {
    next: u16,
    map: RegisterMap,
}

/// What a point holds when the device does not implement it.
fn not_implemented(point: &Point) -> Raw {
    match point.kind.as_str() {
        "int16" | "sunssf" => Raw::U16(0x8000),
        "uint16" | "enum16" | "bitfield16" | "count" => Raw::U16(0xFFFF),
        "int32" => Raw::U32(0x8000_0000),
        "uint32" | "bitfield32" => Raw::U32(0xFFFF_FFFF),
        "float32" => Raw::U32(0x7FC0_0000),
        "int64" => Raw::U64(0x8000_0000_0000_0000),
        "uint64" => Raw::U64(u64::MAX),
        "string" => Raw::Text("", point.size),
        // acc16/32/64 and pad: zero.
        _ => Raw::U64(0),
    }
}

/// A point's value: what the device holds, and the text published for it (`None`: "not
/// implemented", never published).
pub type PointValue<'a> = (&'a str, Raw, Option<&'a str>);

impl SunSpecMap {
    /// "SunS" at `base`; models follow.
    pub fn new(base: u16) -> Self {
        let map = RegisterMap {
            entries: vec![Entry::new(
                "marker",
                Table::Holding,
                base,
                Raw::Text("SunS", 2),
                "SunS",
            )],
            filler: vec![],
        };
        Self {
            next: base + 2,
            map,
        }
    }

    /// Appends model `id` with `repeats` repeats of its repeating group. `values` name points
    /// as `Point` (fixed part) or `group<N>.Point` (repeat N, from 1); their entries are named
    /// `<id>/<point>` (`160/module2/DCA`). Unknown models and points are a defect of the
    /// simulator's table and panic.
    pub fn model(mut self, id: u16, repeats: u16, values: &[PointValue<'_>]) -> Self {
        let Some(def) = sunspec::model(id) else {
            panic!("SunSpec model {id} is not in the table");
        };
        let length = def.fixed_len() + repeats * def.group_len();
        let start = self.next;
        let mut points: Vec<(String, u16, &Point)> = Vec::new();
        let mut at = start;
        for point in &def.points {
            points.push((point.name.clone(), at, point));
            at += point.size;
        }
        if let Some(group) = &def.repeating {
            for index in 1..=repeats {
                for point in &group.points {
                    points.push((format!("{}{index}.{}", group.name, point.name), at, point));
                    at += point.size;
                }
            }
        }
        for (name, address, point) in &points {
            let raw = match name.as_str() {
                "ID" => Raw::U16(id),
                "L" => Raw::U16(length),
                "N" if def.repeating.is_some() => Raw::U16(repeats),
                _ => not_implemented(point),
            };
            for (i, word) in raw.words().into_iter().enumerate() {
                self.map
                    .filler
                    .push((Table::Holding, address + i as u16, word));
            }
        }
        for (name, raw, published) in values {
            let Some((_, address, _)) = points.iter().find(|(n, _, _)| n == name) else {
                panic!("model {id} has no point {name}");
            };
            let field = format!("{id}/{}", name.replace('.', "/"));
            self.map.entries.push(match published {
                Some(text) => Entry::new(&field, Table::Holding, *address, raw.clone(), text),
                None => Entry::unavailable(&field, Table::Holding, *address, raw.clone()),
            });
        }
        self.next = start + 2 + length;
        self
    }

    /// The end marker (ID 0xFFFF, L 0) and the map.
    pub fn end(mut self) -> RegisterMap {
        self.map.filler.extend([
            (Table::Holding, self.next, 0xFFFF),
            (Table::Holding, self.next + 1, 0),
        ]);
        self.map
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_chain_is_laid_out_as_the_specification_says() {
        let map = SunSpecMap::new(40000)
            .model(1, 0, &[("Mn", Raw::Text("Sim", 16), Some("Sim"))])
            .model(103, 0, &[("W", Raw::I16(-5), Some("-5"))])
            .model(160, 2, &[("module2.DCA", Raw::U16(7), Some("7"))])
            .end();
        let device = map.device(1);
        assert_eq!(device.holding(40000), Some(0x5375));
        assert_eq!(device.holding(40001), Some(0x6E53));
        assert_eq!(
            (device.holding(40002), device.holding(40003)),
            (Some(1), Some(66))
        );
        assert_eq!(device.holding(40004), Some(0x5369));
        assert_eq!(
            (device.holding(40070), device.holding(40071)),
            (Some(103), Some(50))
        );
        assert_eq!(device.holding(40072 + 12), Some(0xFFFB));
        // Points left out hold "not implemented": A (uint16) and A_SF (sunssf).
        assert_eq!(device.holding(40072), Some(0xFFFF));
        assert_eq!(device.holding(40076), Some(0x8000));
        assert_eq!(
            (device.holding(40122), device.holding(40123)),
            (Some(160), Some(48))
        );
        // N, the module count, at offset 8 of model 160 (ID, L, 4 SF, Evt×2).
        assert_eq!(device.holding(40122 + 8), Some(2));
        // Module 2's DCA: after the fixed part (10) and one module (20), behind the module's
        // ID and its 8-register IDStr.
        assert_eq!(device.holding(40122 + 10 + 20 + 9), Some(7));
        assert_eq!(device.holding(40172), Some(0xFFFF));
        assert_eq!(map.entry("160/module2/DCA").map(|e| e.address), Some(40161));
    }
}
