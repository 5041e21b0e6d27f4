//! A test's hands and eyes on an X display: the keys a user presses and the pixels they see,
//! through XTEST (input the server treats as a real keyboard's) and `GetImage`.

use std::time::{Duration, Instant};
use x11rb::connection::Connection as _;
use x11rb::protocol::xproto::{
    AtomEnum, ConnectionExt as _, ImageFormat, InputFocus, KEY_PRESS_EVENT, KEY_RELEASE_EVENT, MapState,
    Window,
};
use x11rb::protocol::xtest::ConnectionExt as _;
use x11rb::rust_connection::RustConnection;
use x11rb::wrapper::ConnectionExt as _;

pub struct Display {
    connection: RustConnection,
    root: Window,
}

/// An open window's pixels, RGB, rows from the top.
#[derive(Clone, PartialEq)]
pub struct Shot {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<[u8; 3]>,
}

impl Display {
    pub fn connect(display: &str) -> Display {
        let (connection, screen) = x11rb::connect(Some(display)).expect("connecting to Xvfb");
        let root = connection.setup().roots[screen].root;
        Display { connection, root }
    }

    /// The mapped top-level window whose title starts with `title`, once there is one (at most
    /// `within`); it is given the keyboard.
    pub fn window(&self, title: &str, within: Duration) -> Option<Window> {
        let start = Instant::now();
        while start.elapsed() < within {
            let children = self.connection.query_tree(self.root).unwrap().reply().unwrap().children;
            for window in children {
                let name = self
                    .connection
                    .get_property(false, window, AtomEnum::WM_NAME, AtomEnum::ANY, 0, 256)
                    .unwrap()
                    .reply()
                    .map(|p| p.value)
                    .unwrap_or_default();
                let mapped =
                    self.connection.get_window_attributes(window).unwrap().reply().unwrap().map_state
                        == MapState::VIEWABLE;
                if mapped && name.starts_with(title.as_bytes()) {
                    self.connection.set_input_focus(InputFocus::POINTER_ROOT, window, 0u32).unwrap();
                    self.connection.sync().unwrap();
                    return Some(window);
                }
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        None
    }

    /// Presses and releases the key that types `keysym` (X's keysym, such as 0xffc7 for F10).
    pub fn key(&self, keysym: u32) {
        let setup = self.connection.setup();
        let (first, count) = (setup.min_keycode, setup.max_keycode - setup.min_keycode + 1);
        let map = self.connection.get_keyboard_mapping(first, count).unwrap().reply().unwrap();
        let per = map.keysyms_per_keycode as usize;
        // The key whose first (unshifted) symbol it is: a keysym may also sit in another
        // column of an earlier key, which typed without its modifier types something else.
        let at = (0..map.keysyms.len())
            .step_by(per)
            .find(|&i| map.keysyms[i] == keysym)
            .unwrap_or_else(|| panic!("no key types {keysym:#x} unshifted"));
        let keycode = first + (at / per) as u8;
        for event in [KEY_PRESS_EVENT, KEY_RELEASE_EVENT] {
            self.connection.xtest_fake_input(event, keycode, 0, self.root, 0, 0, 0).unwrap();
        }
        self.connection.sync().unwrap();
    }

    /// What `window` shows now.
    pub fn shot(&self, window: Window) -> Shot {
        let geometry = self.connection.get_geometry(window).unwrap().reply().unwrap();
        let (width, height) = (geometry.width, geometry.height);
        let image = self
            .connection
            .get_image(ImageFormat::Z_PIXMAP, window, 0, 0, width, height, !0)
            .unwrap()
            .reply()
            .unwrap();
        assert_eq!(image.depth, 24, "a 24-bit display (BGRX pixels)");
        let rgb = image.data.chunks_exact(4).map(|p| [p[2], p[1], p[0]]).collect();
        Shot { width: width as u32, height: height as u32, rgb }
    }

    /// The first shot for which `until` holds (at most `within`, panicking after), `gap` apart.
    pub fn shot_until(
        &self,
        window: Window,
        (gap, within): (Duration, Duration),
        what: &str,
        until: impl Fn(&Shot) -> bool,
    ) -> Shot {
        let start = Instant::now();
        loop {
            let shot = self.shot(window);
            if until(&shot) {
                return shot;
            }
            assert!(start.elapsed() < within, "waited {within:?} for the window: {what}");
            std::thread::sleep(gap);
        }
    }

    /// The first shot equal to the one `gap` before it: what the window settles on.
    pub fn settled(&self, window: Window, gap: Duration, within: Duration) -> Shot {
        let last = std::cell::RefCell::new(self.shot(window));
        std::thread::sleep(gap); // else the first comparison is of two shots taken back to back
        self.shot_until(window, (gap, within), "to settle", |now| now == &last.replace(now.clone()))
    }
}

impl Shot {
    /// Has something been drawn: not every pixel one colour?
    pub fn drawn(&self) -> bool {
        self.rgb.iter().any(|p| p != &self.rgb[0])
    }

    /// The smallest rectangle (left, top, width, height) that holds every pixel where `self` and
    /// `other` differ; `None` where they are the same.
    pub fn differs_within(&self, other: &Shot) -> Option<[u32; 4]> {
        assert_eq!((self.width, self.height), (other.width, other.height), "shots of one size");
        let (mut min, mut max) = ((u32::MAX, u32::MAX), (0, 0));
        for (i, (a, b)) in self.rgb.iter().zip(&other.rgb).enumerate() {
            if a != b {
                let (x, y) = (i as u32 % self.width, i as u32 / self.width);
                (min, max) = ((min.0.min(x), min.1.min(y)), (max.0.max(x), max.1.max(y)));
            }
        }
        (min.0 != u32::MAX).then(|| [min.0, min.1, max.0 - min.0 + 1, max.1 - min.1 + 1])
    }

    pub fn save(&self, path: &std::path::Path) {
        let bytes: Vec<u8> = self.rgb.iter().flatten().copied().collect();
        image::save_buffer(path, &bytes, self.width, self.height, image::ColorType::Rgb8).unwrap();
    }
}
