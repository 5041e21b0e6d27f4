//! What a window's panel shows of chapter 08's frame: the settings its keys change, as controls
//! that change them too, then the values a reader wants beside the picture (the sync path, the
//! rays so far) and each pass's GPU time. The chapters hand these to `Window::panel`.

use super::input::Settings;
use crate::clocks::timing::PassTimes;
use std::ops::RangeInclusive;

// ANCHOR: settings
/// The controls for `settings`, one a row beside the key that changes it too: `views` are the
/// composite's views with their names, `radius` the range the radius slider spans, and
/// `overlays` whether the chapter draws them (a checkbox that changed nothing would mislead).
pub fn settings<V: Copy + PartialEq>(
    ui: &mut egui::Ui,
    settings: &mut Settings<V>,
    views: &[(V, &str)],
    radius: RangeInclusive<f32>,
    overlays: bool,
) {
    use egui::Slider;
    ui.spacing_mut().slider_width = 110.0;
    egui::Grid::new("settings").show(ui, |ui| {
        let row = |ui: &mut egui::Ui, name: &str, control: &mut dyn FnMut(&mut egui::Ui), key: &str| {
            ui.label(name);
            control(ui);
            ui.weak(key);
            ui.end_row();
        };
        row(
            ui,
            "rays a frame",
            &mut |ui| {
                ui.add(Slider::new(&mut settings.samples, 1..=256).logarithmic(true));
            },
            "+ -",
        );
        row(
            ui,
            "radius",
            &mut |ui| {
                ui.add(Slider::new(&mut settings.radius, radius.clone()).logarithmic(true));
            },
            "[ ]",
        );
        row(
            ui,
            "power",
            &mut |ui| {
                ui.add(Slider::new(&mut settings.power, 1.0..=3.0));
            },
            "P",
        );
        row(
            ui,
            "blur radius",
            &mut |ui| {
                ui.add(Slider::new(&mut settings.blur, 0..=4));
            },
            "B",
        );
        row(
            ui,
            "view",
            &mut |ui| {
                let shown = views.iter().find(|(v, _)| *v == settings.view).map_or("", |(_, name)| name);
                egui::ComboBox::from_id_salt("view").selected_text(shown).show_ui(ui, |ui| {
                    for (view, name) in views {
                        ui.selectable_value(&mut settings.view, *view, *name);
                    }
                });
            },
            &format!("1-{}", views.len()),
        );
        if overlays {
            row(
                ui,
                "overlays",
                &mut |ui| {
                    ui.checkbox(&mut settings.overlays, "");
                },
                "O",
            );
        }
    });
}
// ANCHOR_END: settings

/// Named values, one a row: `("sync", "semaphores")`.
pub fn values(ui: &mut egui::Ui, rows: &[(&str, String)]) {
    ui.separator();
    egui::Grid::new("values").show(ui, |ui| {
        for (name, value) in rows {
            ui.label(*name);
            ui.monospace(value);
            ui.end_row();
        }
    });
}

/// Each pass's GPU time, the median of its last 60 frames, and the frame's wall-clock time.
pub fn pass_times(ui: &mut egui::Ui, times: &PassTimes) {
    ui.separator();
    egui::Grid::new("pass times").show(ui, |ui| {
        for (pass, ms) in times.recent() {
            ui.label(pass);
            ui.monospace(ms.map_or("-".into(), |ms| format!("{ms:8.2} ms")));
            ui.end_row();
        }
    });
}

/// A control of [`controls`]: a checkbox, or a slider over whole numbers (logarithmic where the
/// range spans more than 64 times its start).
pub enum Control<'a> {
    Toggle(&'a mut bool),
    Count(&'a mut u32, RangeInclusive<u32>),
}

/// Controls one a row, each as (name, control, the key that changes it too: "" for none), for a
/// chapter whose settings are not chapter 08's.
pub fn controls(ui: &mut egui::Ui, rows: &mut [(&str, Control, &str)]) {
    ui.spacing_mut().slider_width = 110.0;
    egui::Grid::new("controls").show(ui, |ui| {
        for (name, control, key) in rows {
            ui.label(*name);
            match control {
                Control::Toggle(on) => ui.checkbox(on, ""),
                Control::Count(value, range) => {
                    let log = *range.start() >= 1 && *range.end() > 64 * *range.start();
                    ui.add(egui::Slider::new(*value, range.clone()).logarithmic(log))
                }
            };
            ui.weak(*key);
            ui.end_row();
        }
    });
}
