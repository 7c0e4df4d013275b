//! The thermistor table against the beta equation computed here in f64.

mod thermal_model;

use strata::thermal::thermistor::{self, TABLE, TABLE_FIRST_C, TABLE_LEN, TABLE_STEP_C};
use thermal_model::{adc_of_temp, temp_of_sum};

/// The generator of `thermistor::TABLE`: the expected 16-conversion sum every 5 °C from -10 °C
/// to 350 °C for the EPCOS 100k (beta 4092) with a 4.7 kΩ pull-up.
fn generate_table() -> Vec<u16> {
    (0..TABLE_LEN)
        .map(|i| {
            let t = f64::from(TABLE_FIRST_C + TABLE_STEP_C * i as i16);
            (16.0 * adc_of_temp(t)).round() as u16
        })
        .collect()
}

#[test]
fn table_is_what_the_generator_produces() {
    let generated = generate_table();
    for (i, (&g, &t)) in generated.iter().zip(TABLE.iter()).enumerate() {
        assert!(g.abs_diff(t) <= 1, "entry {i}: generated {g}, table {t}");
    }
}

/// Prints the table in source form: `cargo test --test thermal_table -- --ignored --nocapture`.
#[test]
#[ignore]
fn print_table() {
    println!("{:?}", generate_table());
}

#[test]
fn table_within_half_a_degree_of_the_equation_from_0_to_300_c() {
    let mut worst = 0.0f64;
    for k in 0..=3000 {
        let t = f64::from(k) * 0.1;
        let sum = (16.0 * adc_of_temp(t)).round();
        let exact = temp_of_sum(sum);
        let got: f64 = thermistor::sum_to_temp(sum as u16).unwrap().to_num();
        worst = worst.max((got - exact).abs());
        assert!((got - t).abs() < 0.5, "at {t} C: table {got}");
    }
    println!("worst table error against the equation over 0..300 C: {worst:.3} C");
    assert!(worst < 0.5);
}
