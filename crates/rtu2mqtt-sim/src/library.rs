//! The device library's simulators: one [`RegisterMap`] per library profile, written from the
//! same vendor register map as the profile (not from the profile), holding the values a test
//! expects the gateway to publish. Values come from the vendors' own worked examples where the
//! documents give them (the ABB readouts, Eastron's 240.5 V float, SunSpec's 1234 × 10^-2), and
//! are otherwise the readings of a plausible installation (a 6 kW inverter at full sun, a
//! meter on a three-wire feeder).

use super::generic::GenericDevice;
use super::register_map::{Entry, Raw, RegisterMap, Table};
use super::sunspec::SunSpecMap;
use rtu2mqtt_modbus::{DeviceIdObject, SlaveId};

/// A library device: its built-in profile's name, its registers, and the objects it answers
/// Read Device Identification with (none: it does not implement the function, and answers
/// exception 01, as the vendor's document leaves it).
#[derive(Debug, Clone)]
pub struct LibraryDevice {
    pub profile: &'static str,
    pub map: RegisterMap,
    pub identification: Vec<DeviceIdObject>,
}

impl LibraryDevice {
    /// The simulated device at `address`: its registers, and its identification if it has one.
    pub fn device(&self, address: SlaveId) -> GenericDevice {
        let device = self.map.device(address);
        if self.identification.is_empty() {
            device
        } else {
            device.with_identification(self.identification.clone())
        }
    }
}

/// Every library device.
pub fn devices() -> Vec<LibraryDevice> {
    vec![
        sdm120(),
        sdm630(),
        abb_a43(),
        sunspec_inverter(),
        growatt_min(),
        iem3155(),
    ]
}

/// The library device of `profile`, if it is one.
pub fn device(profile: &str) -> Option<LibraryDevice> {
    devices().into_iter().find(|d| d.profile == profile)
}

fn input(field: &str, address: u16, value: f32, published: &str) -> Entry {
    Entry::new(field, Table::Input, address, Raw::F32(value), published)
}

/// Eastron SDM120: floats in input registers.
pub fn sdm120() -> LibraryDevice {
    let entries = vec![
        input("voltage", 0x0000, 240.5, "240.5"),
        input("current", 0x0006, 4.25, "4.250"),
        input("power", 0x000C, 1006.5, "1006.5"),
        input("apparent_power", 0x0012, 1022.0, "1022.0"),
        input("reactive_power", 0x0018, -180.5, "-180.5"),
        input("power_factor", 0x001E, 0.985, "0.985"),
        input("phase_angle", 0x0024, 9.5, "9.5"),
        input("frequency", 0x0046, 49.98, "49.98"),
        input("import_energy", 0x0048, 1234.567, "1234.567"),
        input("export_energy", 0x004A, 12.5, "12.500"),
        input("import_reactive_energy", 0x004C, 321.25, "321.250"),
        input("export_reactive_energy", 0x004E, 4.5, "4.500"),
        input("total_energy", 0x0156, 1247.067, "1247.067"),
        input("total_reactive_energy", 0x0158, 325.75, "325.750"),
    ];
    LibraryDevice {
        profile: "eastron-sdm120",
        identification: Vec::new(),
        map: RegisterMap::over_zeros(
            entries,
            &[(Table::Input, 0x0000, 0x50), (Table::Input, 0x0156, 4)],
        ),
    }
}

/// Eastron SDM630 V2: floats in input registers, three phases.
pub fn sdm630() -> LibraryDevice {
    let mut entries = Vec::new();
    let phases: [(&str, u16, [f32; 3], [&str; 3]); 6] = [
        (
            "voltage",
            0x00,
            [230.5, 231.0, 229.5],
            ["230.5", "231.0", "229.5"],
        ),
        (
            "current",
            0x06,
            [5.125, 4.5, 6.0],
            ["5.125", "4.500", "6.000"],
        ),
        (
            "power",
            0x0C,
            [1150.5, 1020.0, -250.5],
            ["1150.5", "1020.0", "-250.5"],
        ),
        (
            "apparent_power",
            0x12,
            [1181.5, 1040.5, 1378.5],
            ["1181.5", "1040.5", "1378.5"],
        ),
        (
            "reactive_power",
            0x18,
            [120.5, -60.0, 0.0],
            ["120.5", "-60.0", "0.0"],
        ),
        (
            "power_factor",
            0x1E,
            [0.974, 0.98, -0.182],
            ["0.974", "0.980", "-0.182"],
        ),
    ];
    for (name, start, values, texts) in phases {
        for phase in 0..3 {
            entries.push(input(
                &format!("{name}_l{}", phase + 1),
                start + 2 * phase as u16,
                values[phase],
                texts[phase],
            ));
        }
    }
    entries.extend([
        input("total_power", 0x34, 1920.0, "1920.0"),
        input("total_apparent_power", 0x38, 3600.5, "3600.5"),
        input("total_reactive_power", 0x3C, 60.5, "60.5"),
        input("total_power_factor", 0x3E, 0.533, "0.533"),
        input("frequency", 0x46, 50.01, "50.01"),
        input("import_energy", 0x48, 45678.5, "45678.500"),
        input("export_energy", 0x4A, 987.25, "987.250"),
        input("import_reactive_energy", 0x4C, 1500.125, "1500.125"),
        input("export_reactive_energy", 0x4E, 200.0, "200.000"),
        input("voltage_l1_l2", 0xC8, 399.5, "399.5"),
        input("voltage_l2_l3", 0xCA, 400.5, "400.5"),
        input("voltage_l3_l1", 0xCC, 398.0, "398.0"),
        input("neutral_current", 0xE0, 1.25, "1.250"),
        input("total_energy", 0x156, 46665.75, "46665.750"),
        input("total_reactive_energy", 0x158, 1700.125, "1700.125"),
    ]);
    LibraryDevice {
        profile: "eastron-sdm630",
        identification: Vec::new(),
        map: RegisterMap::over_zeros(
            entries,
            &[
                (Table::Input, 0x0000, 0x50),
                (Table::Input, 0x00C8, 0x1A),
                (Table::Input, 0x0156, 4),
            ],
        ),
    }
}

/// ABB A43/A44: 64-bit energies and 32-bit instantaneous values in holding registers, with
/// the values of the manual's readout examples.
pub fn abb_a43() -> LibraryDevice {
    let h = |field: &str, address: u16, raw: Raw, text: &str| {
        Entry::new(field, Table::Holding, address, raw, text)
    };
    let mut entries = vec![
        // Totals: the sums of the manual's per-phase example values.
        h("active_import", 0x5000, Raw::U64(856_520), "8565.20"),
        h("active_export", 0x5004, Raw::U64(201_224), "2012.24"),
        h("active_net", 0x5008, Raw::I64(655_296), "6552.96"),
        h("reactive_import", 0x500C, Raw::U64(343_099), "3430.99"),
        h("reactive_export", 0x5010, Raw::U64(151_680), "1516.80"),
        h("reactive_net", 0x5014, Raw::I64(-15_000), "-150.00"),
        // Per phase: the manual's readout of 0x5460.
        h("active_import_l1", 0x5460, Raw::U64(0x31292), "2013.62"),
        h("active_import_l2", 0x5464, Raw::U64(0x498E1), "3012.81"),
        h("active_import_l3", 0x5468, Raw::U64(0x56655), "3538.77"),
        h("active_export_l1", 0x546C, Raw::U64(0x923A), "374.34"),
        h("active_export_l2", 0x5470, Raw::U64(0x11C9B), "728.59"),
        h("active_export_l3", 0x5474, Raw::U64(0x16333), "909.31"),
    ];
    // Instantaneous values: the manual's readout of 0x5B00 where it gives them.
    let u32s: [(&str, u16, u32, &str); 10] = [
        ("voltage_l1_n", 0x5B00, 2301, "230.1"),
        ("voltage_l2_n", 0x5B02, 2332, "233.2"),
        ("voltage_l3_n", 0x5B04, 2318, "231.8"),
        ("voltage_l1_l2", 0x5B06, 4030, "403.0"),
        ("voltage_l3_l2", 0x5B08, 0x0FCA, "404.2"),
        ("voltage_l1_l3", 0x5B0A, 0x0FC0, "403.2"),
        ("current_l1", 0x5B0C, 0x65, "1.01"),
        ("current_l2", 0x5B0E, 0xC9, "2.01"),
        ("current_l3", 0x5B10, 0x12E, "3.02"),
        ("current_n", 0x5B12, 0x86, "1.34"),
    ];
    for (field, address, raw, text) in u32s {
        entries.push(h(field, address, Raw::U32(raw), text));
    }
    let i32s: [(&str, u16, i32, &str); 12] = [
        ("active_power", 0x5B14, 0x1E8E4, "1251.56"),
        ("active_power_l1", 0x5B16, 0x5AE2, "232.66"),
        ("active_power_l2", 0x5B18, 0xB097, "452.07"),
        ("active_power_l3", 0x5B1A, 0xDD6B, "566.83"),
        ("reactive_power", 0x5B1C, 0x7541, "300.17"),
        ("reactive_power_l1", 0x5B1E, 0x1C, "0.28"),
        ("reactive_power_l2", 0x5B20, -12214, "-122.14"),
        ("reactive_power_l3", 0x5B22, 0xA4DB, "422.03"),
        ("apparent_power", 0x5B24, 0x225C3, "1407.39"),
        ("apparent_power_l1", 0x5B26, 0x5AE2, "232.66"),
        ("apparent_power_l2", 0x5B28, 0xB6DF, "468.15"),
        ("apparent_power_l3", 0x5B2A, 0x11402, "706.58"),
    ];
    for (field, address, raw, text) in i32s {
        entries.push(h(field, address, Raw::I32(raw), text));
    }
    entries.extend([
        h("frequency", 0x5B2C, Raw::U16(0x1383), "49.95"),
        h("power_factor", 0x5B3A, Raw::I16(0x3CC), "0.972"),
        h("power_factor_l1", 0x5B3B, Raw::I16(0x3E8), "1.000"),
        h("power_factor_l2", 0x5B3C, Raw::I16(0x3C6), "0.966"),
        h("power_factor_l3", 0x5B3D, Raw::I16(-950), "-0.950"),
    ]);
    // The manual's readout: phase angles after the frequency, 0xFFFF where no data exists.
    let mut map = RegisterMap::over_zeros(
        entries,
        &[
            (Table::Holding, 0x5000, 0x18),
            (Table::Holding, 0x5460, 0x18),
            (Table::Holding, 0x5B00, 0x3E),
        ],
    );
    let angles: [u16; 13] = [
        0x0087, 0x0000, 0xFF6A, 0x016F, 0x0000, 0x04AF, 0xFB4E, 0xFFFF, 0xFFFF, 0xFFFF, 0xFFF3,
        0x0409, 0xFCAE,
    ];
    for (i, word) in angles.iter().enumerate() {
        map.filler.push((Table::Holding, 0x5B2D + i as u16, *word));
    }
    LibraryDevice {
        profile: "abb-a43",
        identification: Vec::new(),
        map,
    }
}

/// Growatt MIN TL-X at full sun: input registers with 32-bit values as high/low word pairs
/// (the protocol's "H"/"L"), the power limit and the ASCII nameplate in holding registers, at
/// the addresses the protocol prints (bus addresses).
pub fn growatt_min() -> LibraryDevice {
    let input = |field: &str, address: u16, raw: Raw, text: &str| {
        Entry::new(field, Table::Input, address, raw, text)
    };
    let holding = |field: &str, address: u16, raw: Raw, text: &str| {
        Entry::new(field, Table::Holding, address, raw, text)
    };
    let entries = vec![
        input("inverter_status", 3000, Raw::U16(1), "normal"),
        input("pv_power", 3001, Raw::U32(62_615), "6261.5"),
        input("pv1_voltage", 3003, Raw::U16(3_604), "360.4"),
        input("pv1_current", 3004, Raw::U16(92), "9.2"),
        input("pv1_power", 3005, Raw::U32(33_157), "3315.7"),
        input("pv2_voltage", 3007, Raw::U16(3_386), "338.6"),
        input("pv2_current", 3008, Raw::U16(87), "8.7"),
        input("pv2_power", 3009, Raw::U32(29_458), "2945.8"),
        input("ac_power", 3023, Raw::U32(59_870), "5987.0"),
        input("grid_frequency", 3025, Raw::U16(5_001), "50.01"),
        input("grid_voltage", 3026, Raw::U16(2_334), "233.4"),
        input("grid_current", 3027, Raw::U16(257), "25.7"),
        input("grid_apparent_power", 3028, Raw::U32(59_984), "5998.4"),
        // 7000 h in 0.5 s counts, and one more: the high word is 0x0301.
        input("work_time", 3047, Raw::U32(50_400_001), "25200000.5"),
        input("energy_today", 3049, Raw::U32(312), "31.2"),
        input("energy_total", 3051, Raw::U32(182_347), "18234.7"),
        input("pv_energy_total", 3053, Raw::U32(189_120), "18912.0"),
        input("pv1_energy_today", 3055, Raw::U32(162), "16.2"),
        input("pv1_energy_total", 3057, Raw::U32(98_765), "9876.5"),
        input("pv2_energy_today", 3059, Raw::U32(157), "15.7"),
        input("pv2_energy_total", 3061, Raw::U32(90_355), "9035.5"),
        input("inverter_temperature", 3093, Raw::I16(452), "45.2"),
        input("ipm_temperature", 3094, Raw::I16(518), "51.8"),
        input("boost_temperature", 3095, Raw::I16(387), "38.7"),
        input("output_percent", 3101, Raw::U16(99), "99"),
        input("fault_code", 3105, Raw::U16(0), "0"),
        input("warning_code", 3106, Raw::U16(0), "0"),
        holding("active_power_rate", 3, Raw::U16(100), "100"),
        holding("firmware_version", 9, Raw::Text("GH1.0", 3), "GH1.0"),
        holding(
            "serial_number",
            23,
            Raw::Text("NTD2C15003", 5),
            "NTD2C15003",
        ),
    ];
    LibraryDevice {
        profile: "growatt-min",
        identification: Vec::new(),
        map: RegisterMap::over_zeros(
            entries,
            &[
                (Table::Input, 3000, 63),
                (Table::Input, 3093, 14),
                (Table::Holding, 3, 1),
                (Table::Holding, 9, 19),
            ],
        ),
    }
}

/// Schneider iEM3155 on a three-wire feeder (no neutral, so the phase-to-neutral voltages are
/// NaN): Float32 values, Int64 energies in Wh and UTF-8 text, all in holding registers, written
/// with the manual's 1-based register numbers.
pub fn iem3155() -> LibraryDevice {
    // The frame carries the manual's register number minus one.
    let h = |field: &str, register: u16, raw: Raw, text: &str| {
        Entry::new(field, Table::Holding, register - 1, raw, text)
    };
    let nan = |field: &str, register: u16| {
        Entry::unavailable(
            field,
            Table::Holding,
            register - 1,
            Raw::F32(f32::from_bits(0xFFC0_0000)),
        )
    };
    let entries = vec![
        h(
            "meter_name",
            30,
            Raw::Text("Verteilung Süd", 20),
            "Verteilung Süd",
        ),
        h("meter_model", 50, Raw::Text("iEM3155", 20), "iEM3155"),
        h(
            "manufacturer",
            70,
            Raw::Text("Schneider Electric", 20),
            "Schneider Electric",
        ),
        h("serial_number", 130, Raw::U32(2_137_004_512), "2137004512"),
        h("hardware_revision", 136, Raw::Text("1.0.0", 5), "1.0.0"),
        h("operation_time", 2004, Raw::U32(31_536_000), "31536000"),
        h("power_system", 2016, Raw::U16(3), "3ph3w"),
        h("nominal_frequency", 2017, Raw::U16(50), "50"),
        h("current_l1", 3000, Raw::F32(11.5), "11.500"),
        h("current_l2", 3002, Raw::F32(11.25), "11.250"),
        h("current_l3", 3004, Raw::F32(11.75), "11.750"),
        h("current_avg", 3010, Raw::F32(11.5), "11.500"),
        h("voltage_l1_l2", 3020, Raw::F32(400.5), "400.5"),
        h("voltage_l2_l3", 3022, Raw::F32(398.0), "398.0"),
        h("voltage_l3_l1", 3024, Raw::F32(401.5), "401.5"),
        h("voltage_ll_avg", 3026, Raw::F32(400.0), "400.0"),
        nan("voltage_l1_n", 3028),
        nan("voltage_l2_n", 3030),
        nan("voltage_l3_n", 3032),
        nan("voltage_ln_avg", 3036),
        h("power_l1", 3054, Raw::F32(2.625), "2.625"),
        h("power_l2", 3056, Raw::F32(2.5), "2.500"),
        h("power_l3", 3058, Raw::F32(2.75), "2.750"),
        h("total_power", 3060, Raw::F32(7.875), "7.875"),
        h("total_reactive_power", 3068, Raw::F32(1.25), "1.250"),
        h("total_apparent_power", 3076, Raw::F32(7.974), "7.974"),
        h("power_factor", 3084, Raw::F32(0.988), "0.988"),
        h("frequency", 3110, Raw::F32(50.02), "50.02"),
        h("active_import", 3204, Raw::I64(12_345_678), "12345.678"),
        h("active_export", 3208, Raw::I64(1_234), "1.234"),
        h("reactive_import", 3220, Raw::I64(2_345_678), "2345.678"),
        h("reactive_export", 3224, Raw::I64(0), "0.000"),
        h("partial_active_import", 3256, Raw::I64(345_678), "345.678"),
        h("partial_reactive_import", 3272, Raw::I64(45_678), "45.678"),
    ];
    LibraryDevice {
        profile: "schneider-iem3155",
        // The manual's Read Device Identification: the vendor, the commercial reference as the
        // product code, the firmware revision as XXX.YYY.ZZZ.
        identification: vec![
            DeviceIdObject::text(0x00, "Schneider Electric"),
            DeviceIdObject::text(0x01, "A9MEM3155"),
            DeviceIdObject::text(0x02, "002.001.004"),
        ],
        map: RegisterMap::over_zeros(
            entries,
            &[
                (Table::Holding, 29, 60),
                (Table::Holding, 129, 11),
                (Table::Holding, 2003, 14),
                (Table::Holding, 2999, 38),
                (Table::Holding, 3053, 58),
                (Table::Holding, 3203, 24),
                (Table::Holding, 3255, 20),
            ],
        ),
    }
}

/// The SunSpec points of the simulated inverter and the `sunspec-inverter` field that reads
/// each: (model, point, field).
pub const SUNSPEC_FIELDS: &[(u16, &str, &str)] = &[
    (1, "Mn", "manufacturer"),
    (1, "Md", "model"),
    (1, "Vr", "version"),
    (1, "SN", "serial_number"),
    (1, "DA", "device_address"),
    (103, "A", "ac_current"),
    (103, "AphA", "ac_current_l1"),
    (103, "AphB", "ac_current_l2"),
    (103, "AphC", "ac_current_l3"),
    (103, "A_SF", "current_sf"),
    (103, "PPVphAB", "voltage_l1_l2"),
    (103, "PPVphBC", "voltage_l2_l3"),
    (103, "PPVphCA", "voltage_l3_l1"),
    (103, "PhVphA", "voltage_l1"),
    (103, "PhVphB", "voltage_l2"),
    (103, "PhVphC", "voltage_l3"),
    (103, "V_SF", "voltage_sf"),
    (103, "W", "ac_power"),
    (103, "W_SF", "ac_power_sf"),
    (103, "Hz", "frequency"),
    (103, "Hz_SF", "frequency_sf"),
    (103, "VA", "apparent_power"),
    (103, "VA_SF", "apparent_power_sf"),
    (103, "VAr", "reactive_power"),
    (103, "VAr_SF", "reactive_power_sf"),
    (103, "PF", "power_factor"),
    (103, "PF_SF", "power_factor_sf"),
    (103, "WH", "energy"),
    (103, "WH_SF", "energy_sf"),
    (103, "DCA", "dc_current"),
    (103, "DCA_SF", "dc_current_sf"),
    (103, "DCV", "dc_voltage"),
    (103, "DCV_SF", "dc_voltage_sf"),
    (103, "DCW", "dc_power"),
    (103, "DCW_SF", "dc_power_sf"),
    (103, "TmpCab", "cabinet_temperature"),
    (103, "TmpSnk", "heat_sink_temperature"),
    (103, "TmpTrns", "transformer_temperature"),
    (103, "TmpOt", "other_temperature"),
    (103, "Tmp_SF", "temperature_sf"),
    (103, "St", "operating_state"),
    (103, "Evt1", "events"),
];

/// The SunSpec inverter's chain at base 40000: model 1, model 103, model 160 with two MPPT
/// modules, the end marker. Entries are named `<model>/<point>`.
pub fn sunspec_chain() -> RegisterMap {
    let na = None;
    SunSpecMap::new(40000)
        .model(
            1,
            0,
            &[
                ("Mn", Raw::Text("Sim Solar", 16), Some("Sim Solar")),
                ("Md", Raw::Text("SIM-10K-3P", 16), Some("SIM-10K-3P")),
                ("Vr", Raw::Text("1.4.2", 8), Some("1.4.2")),
                ("SN", Raw::Text("SIM0001234", 16), Some("SIM0001234")),
                ("DA", Raw::U16(1), Some("1")),
            ],
        )
        .model(
            103,
            0,
            &[
                ("A", Raw::U16(2345), Some("23.45")),
                ("AphA", Raw::U16(782), Some("7.82")),
                ("AphB", Raw::U16(781), Some("7.81")),
                ("AphC", Raw::U16(782), Some("7.82")),
                ("A_SF", Raw::I16(-2), Some("-2")),
                ("PPVphAB", Raw::U16(0xFFFF), na),
                ("PPVphBC", Raw::U16(0xFFFF), na),
                ("PPVphCA", Raw::U16(0xFFFF), na),
                ("PhVphA", Raw::U16(2301), Some("230.1")),
                ("PhVphB", Raw::U16(2305), Some("230.5")),
                ("PhVphC", Raw::U16(2298), Some("229.8")),
                ("V_SF", Raw::I16(-1), Some("-1")),
                ("W", Raw::I16(5321), Some("5321")),
                ("W_SF", Raw::I16(0), Some("0")),
                ("Hz", Raw::U16(4998), Some("49.98")),
                ("Hz_SF", Raw::I16(-2), Some("-2")),
                ("VA", Raw::U16(0x8000), na),
                ("VA_SF", Raw::U16(0x8000), na),
                ("VAr", Raw::I16(-123), Some("-123")),
                ("VAr_SF", Raw::I16(0), Some("0")),
                ("PF", Raw::I16(9850), Some("98.50")),
                ("PF_SF", Raw::I16(-2), Some("-2")),
                ("WH", Raw::U32(12_345_678), Some("123456780")),
                ("WH_SF", Raw::I16(1), Some("1")),
                // The specification's example: 1234 with a scale factor of -2 is 12.34.
                ("DCA", Raw::U16(1234), Some("12.34")),
                ("DCA_SF", Raw::I16(-2), Some("-2")),
                ("DCV", Raw::U16(6100), Some("610.0")),
                ("DCV_SF", Raw::I16(-1), Some("-1")),
                ("DCW", Raw::I16(5500), Some("5500")),
                ("DCW_SF", Raw::I16(0), Some("0")),
                ("TmpCab", Raw::I16(415), Some("41.5")),
                ("TmpSnk", Raw::U16(0x8000), na),
                ("TmpTrns", Raw::U16(0x8000), na),
                ("TmpOt", Raw::U16(0x8000), na),
                ("Tmp_SF", Raw::I16(-1), Some("-1")),
                ("St", Raw::U16(4), Some("mppt")),
                ("Evt1", Raw::U32(0), Some("0")),
            ],
        )
        .model(
            160,
            2,
            &[
                ("DCA_SF", Raw::I16(-2), Some("-2")),
                ("DCV_SF", Raw::I16(-1), Some("-1")),
                ("DCW_SF", Raw::I16(0), Some("0")),
                ("DCWH_SF", Raw::I16(0), Some("0")),
                ("module1.ID", Raw::U16(1), Some("1")),
                ("module1.IDStr", Raw::Text("String 1", 8), Some("String 1")),
                ("module1.DCA", Raw::U16(620), Some("6.20")),
                ("module1.DCV", Raw::U16(6120), Some("612.0")),
                ("module1.DCW", Raw::U16(3794), Some("3794")),
                ("module2.ID", Raw::U16(2), Some("2")),
                ("module2.IDStr", Raw::Text("String 2", 8), Some("String 2")),
                ("module2.DCA", Raw::U16(614), Some("6.14")),
                ("module2.DCV", Raw::U16(2800), Some("280.0")),
                ("module2.DCW", Raw::U16(1719), Some("1719")),
            ],
        )
        .end()
}

/// The SunSpec inverter as the `sunspec-inverter` profile names its fields.
pub fn sunspec_inverter() -> LibraryDevice {
    let mut map = sunspec_chain();
    let mut renamed = Vec::new();
    for entry in map.entries.drain(..) {
        let field = if entry.field == "marker" {
            Some("sunspec_marker")
        } else {
            SUNSPEC_FIELDS
                .iter()
                .find(|(model, point, _)| entry.field == format!("{model}/{point}"))
                .map(|(_, _, field)| *field)
        };
        match field {
            Some(field) => renamed.push(Entry {
                field: field.to_string(),
                ..entry
            }),
            // Points the profile does not read stay in the device's memory.
            None => {
                for (i, word) in entry.raw.words().into_iter().enumerate() {
                    map.filler
                        .push((entry.table, entry.address + i as u16, word));
                }
            }
        }
    }
    map.entries = renamed;
    LibraryDevice {
        profile: "sunspec-inverter",
        identification: Vec::new(),
        map,
    }
}
