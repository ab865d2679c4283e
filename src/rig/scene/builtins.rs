//! The built-in scenes, from easy to impossible (one function per scene on top of a shared
//! base), and loading a scene by name or from a JSON file.
//!
//! Sizes: 640×480 camera pixels, 800×600 projector pixels; distances in metres (see [`super`]).

use super::{
    Albedo, Ambient, CameraModel, Drift, Glare, Interreflection, Latency, Noise, Pose,
    ProjectorModel, Scene, Specular, Subsurface, Surface,
};
use crate::error::{Error, Result};

/// Names of the built-in scenes, from easy to impossible.
pub const BUILTIN: &[&str] = &[
    "white-plane",
    "textured-plane",
    "curved",
    "curved-ambient",
    "dark-texture",
    "specular-corner",
    "defocus-noise",
    "translucent",
    "white-segment",
    "step",
    "drift",
];

/// The built-in sets of projectors on one surface ([`Scene::more_projectors`]), simulated
/// together by [`crate::rig::SetSimulator`].
pub const SETS: &[&str] = &["tiled", "stacked"];

/// A built-in scene by name, or a scene description from a JSON file (as `compend sim show`
/// prints it) when `name_or_path` is a path to a file.
pub fn load(name_or_path: &str) -> Result<Scene> {
    if BUILTIN.contains(&name_or_path) || SETS.contains(&name_or_path) {
        return builtin(name_or_path);
    }
    let path = std::path::Path::new(name_or_path);
    if !path.is_file() {
        return builtin(name_or_path);
    }
    let text = crate::files::read_text(path, "a scene description (JSON)")?;
    let scene: Scene = serde_json::from_str(&text).map_err(|e| {
        Error::Input(format!(
            "{}: not a scene description ({e}); `compend sim show NAME` prints one",
            path.display()
        ))
    })?;
    // A scene's own errors name its `name`; the file it came from is what the user edits.
    scene.validate().map_err(|e| match e {
        Error::Input(why) => Error::Input(format!("{}: {why}", path.display())),
        other => other,
    })?;
    Ok(scene)
}

/// The built-in scene called `name` (at 640×480 camera, 800×600 projector).
pub fn builtin(name: &str) -> Result<Scene> {
    let base = base_scene();
    let scene = match name {
        "white-plane" => white_plane(name, base),
        "textured-plane" => textured_plane(name, base),
        "curved" => curved(name, base),
        "curved-ambient" => curved_ambient(name, base),
        "dark-texture" => dark_texture(name, base),
        "specular-corner" => specular_corner(name, base),
        "defocus-noise" => defocus_noise(name, base),
        "translucent" => translucent(name, base),
        "white-segment" => white_segment(name, base),
        "step" => step(name, base),
        "drift" => drift(name, base),
        "tiled" => tiled(name, base),
        "stacked" => stacked(name, base),
        other => {
            return Err(Error::Input(format!(
                "unknown scene {other:?} (neither a built-in scene nor a scene file); built-in \
                 scenes: {}; sets of projectors: {}",
                BUILTIN.join(", "),
                SETS.join(", ")
            )));
        }
    };
    Ok(scene)
}

// One function per built-in scene, in the order of `BUILTIN`: `base` with the scene's name,
// summary and what sets it apart.

fn white_plane(name: &str, base: Scene) -> Scene {
    Scene {
        name: name.into(),
        summary: "a white matte wall facing the camera: geometry and response curves only".into(),
        ..base
    }
}

fn textured_plane(name: &str, base: Scene) -> Scene {
    Scene {
        name: name.into(),
        summary: "a flat, slightly turned wall with a colourful texture".into(),
        surface: Surface::Plane {
            distance: 2.0,
            tilt_deg: [12.0, -3.0],
        },
        albedo: light_texture(),
        ..base
    }
}

fn curved(name: &str, base: Scene) -> Scene {
    Scene {
        name: name.into(),
        summary: "a textured convex cylinder (a column or a bulging curtain)".into(),
        surface: Surface::Cylinder {
            distance: 1.9,
            radius: 1.3,
            convex: true,
        },
        albedo: light_texture(),
        ..base
    }
}

fn curved_ambient(name: &str, base: Scene) -> Scene {
    Scene {
        name: name.into(),
        summary: "a textured curtain-like wave under strong warm ambient light from the left"
            .into(),
        surface: Surface::Wave {
            distance: 2.0,
            amplitude: 0.05,
            period: 0.45,
            angle_deg: 0.0,
            phase_deg: 30.0,
        },
        albedo: light_texture(),
        ambient: Ambient {
            offset: [0.08, 0.06, 0.035],
            gradient: [0.30, 0.16, 0.03],
            direction_deg: 180.0,
        },
        ..base
    }
}

fn dark_texture(name: &str, base: Scene) -> Scene {
    Scene {
        name: name.into(),
        summary: "a dark, saturated texture: full compensation is physically impossible in \
              places"
            .into(),
        surface: Surface::Plane {
            distance: 2.0,
            tilt_deg: [-6.0, 2.0],
        },
        albedo: Albedo::Texture {
            palette: vec![
                [0.45, 0.03, 0.02],
                [0.04, 0.04, 0.03],
                [0.03, 0.06, 0.42],
                [0.05, 0.28, 0.05],
                [0.30, 0.02, 0.30],
                [0.40, 0.30, 0.02],
            ],
            scale: 0.22,
            shade: 0.6,
            sharpness: 3.0,
        },
        ..base
    }
}

fn specular_corner(name: &str, base: Scene) -> Scene {
    let mut s = Scene {
        name: name.into(),
        summary: "an inside corner with a glossy finish: projector highlights that clip, \
                  light bouncing between the walls, and a reflected room lamp"
            .into(),
        surface: Surface::Corner {
            distance: 2.1,
            slope: 0.22,
            edge_x: 0.05,
        },
        albedo: Albedo::Texture {
            palette: vec![[0.80, 0.78, 0.72], [0.70, 0.74, 0.80], [0.82, 0.66, 0.60]],
            scale: 0.3,
            shade: 0.25,
            sharpness: 1.5,
        },
        specular: Some(Specular {
            strength: 0.6,
            shininess: 150.0,
        }),
        interreflection: Some(Interreflection {
            strength: 0.25,
            radius: 0.12,
        }),
        glare: Some(Glare {
            rgb: [0.10, 0.09, 0.07],
            centre: [0.3, 0.35],
            radius: 0.05,
        }),
        ..base
    };
    s.camera.exposure = 0.85;
    s
}

fn defocus_noise(name: &str, base: Scene) -> Scene {
    let mut s = Scene {
        name: name.into(),
        summary: "a textured concave surface with the projector out of focus and a noisy \
                  camera (high gain)"
            .into(),
        surface: Surface::Cylinder {
            distance: 2.1,
            radius: 2.2,
            convex: false,
        },
        albedo: light_texture(),
        ..base
    };
    s.projector.defocus_px = 2.5;
    s.camera.noise = Noise {
        shot: 0.003,
        read: 0.012,
    };
    s
}

fn step(name: &str, base: Scene) -> Scene {
    let mut s = Scene {
        name: name.into(),
        summary: "a block standing in front of a wall: the projector cannot reach the \
                  strip the block shadows (self-occlusion)"
            .into(),
        surface: Surface::Step {
            distance: 2.2,
            depth: 0.4,
            edge_x: 0.08,
        },
        albedo: light_texture(),
        ..base
    };
    // A wider baseline, so the shadow strip is clearly visible from the camera.
    s.projector.pose = Pose::looking_at([0.35, -0.06, 0.0], [0.0, 0.0, 2.0], 0.4);
    s
}

fn drift(name: &str, base: Scene) -> Scene {
    let mut s = Scene {
        name: name.into(),
        summary: "the curved textured scene with a projector that moves by about 1.5 \
                  pixels after calibration"
            .into(),
        surface: Surface::Cylinder {
            distance: 1.9,
            radius: 1.3,
            convex: true,
        },
        albedo: light_texture(),
        ..base
    };
    s.drift = Some(Drift {
        shift_px: [1.5, -1.0],
    });
    s
}

fn translucent(name: &str, base: Scene) -> Scene {
    Scene {
        name: name.into(),
        summary: "a textured translucent surface (skin-like: a mannequin, a wax figure, a \
                  lampshade): light re-emerges millimetres from where it entered, furthest in \
                  red"
        .into(),
        surface: Surface::Plane {
            distance: 1.2,
            tilt_deg: [8.0, 4.0],
        },
        albedo: light_texture(),
        // Skin's diffusion lengths (see `Subsurface`); 80 % of the diffuse reflection
        // sub-surface (an assumption: the rest leaves at the surface).
        subsurface: Some(Subsurface {
            share: 0.8,
            radius_mm: [3.7, 1.4, 0.7],
        }),
        ..base
    }
}

fn white_segment(name: &str, base: Scene) -> Scene {
    let mut s = textured_plane(name, base);
    s.summary = "the textured wall lit by a single-chip DLP projector with a white segment: \
                 greys twice as bright as their primaries add up to"
        .into();
    s.projector.white_boost = 1.0;
    // The camera exposed for this projector's white, as exposure ranging would set it: white
    // is (1 + white_boost) times brighter than the other scenes' projector makes it.
    s.camera.exposure /= 1.0 + s.projector.white_boost;
    s
}

// The sets, in the order of `SETS`.

/// Two projectors side by side on a concave textured wall, their pictures overlapping by about
/// a fifth of each one's width; the right one an older unit: dimmer (about 80 %), its white
/// yellower, its black higher, as two units of different ages are.
fn tiled(name: &str, base: Scene) -> Scene {
    // Each projector's picture is 2·2.2·tan(17°) ≈ 1.35 m wide on the wall; centres 1.08 m
    // apart leave 0.27 m, 20 % of it, lit by both. The camera (62°) sees both pictures whole.
    let left = ProjectorModel {
        hfov_deg: 34.0,
        pose: Pose::looking_at([-0.45, -0.05, 0.0], [-0.54, 0.0, 2.2], 0.3),
        ..base.projector.clone()
    };
    let right = ProjectorModel {
        hfov_deg: 34.0,
        pose: Pose::looking_at([0.45, -0.04, 0.0], [0.54, 0.0, 2.2], -0.5),
        gamma: [2.3, 2.25, 2.2],
        mixing: [[0.78, 0.05, 0.01], [0.03, 0.76, 0.03], [0.01, 0.03, 0.63]],
        black: [0.003, 0.003, 0.004],
        vignetting: 0.16,
        ..base.projector.clone()
    };
    Scene {
        name: name.into(),
        summary: "two projectors tiled on a concave textured wall (20 % overlap); the right one \
                  older: dimmer, yellower, a higher black"
            .into(),
        camera: CameraModel {
            hfov_deg: 62.0,
            ..base.camera.clone()
        },
        projector: left,
        more_projectors: vec![right],
        surface: Surface::Cylinder {
            distance: 2.2,
            radius: 3.5,
            convex: false,
        },
        albedo: light_texture(),
        ..base
    }
}

/// Two projectors stacked on `dark-texture`'s wall, both filling about the same picture: twice
/// the light where one alone is too dark.
fn stacked(name: &str, base: Scene) -> Scene {
    let dark = dark_texture(name, base.clone());
    let second = ProjectorModel {
        pose: Pose::looking_at([-0.10, -0.06, 0.0], [0.0, 0.0, 2.0], -0.3),
        mixing: [[0.90, 0.06, 0.01], [0.04, 0.92, 0.03], [0.01, 0.05, 0.93]],
        ..base.projector.clone()
    };
    Scene {
        name: name.into(),
        summary: "two projectors stacked on a dark, saturated texture: together they reach \
                  what one cannot"
            .into(),
        more_projectors: vec![second],
        ..dark
    }
}

/// The shared defaults: a white wall 2 m away, camera at the origin, projector 12 cm to the
/// right and 5 cm up, aimed at the wall's centre; mild colour crosstalk on both devices.
fn base_scene() -> Scene {
    Scene {
        name: String::new(),
        summary: String::new(),
        camera: CameraModel {
            width: 640,
            height: 480,
            hfov_deg: 50.0,
            pose: Pose::origin(),
            mixing: [[0.94, 0.05, 0.01], [0.03, 0.94, 0.03], [0.01, 0.05, 0.94]],
            exposure: 1.1,
            gamma: 2.2,
            vignetting: 0.15,
            noise: Noise {
                shot: 0.0004,
                read: 0.002,
            },
            blur_px: 0.0,
        },
        projector: ProjectorModel {
            width: 800,
            height: 600,
            hfov_deg: 38.0,
            pose: Pose::looking_at([0.12, -0.05, 0.0], [0.0, 0.0, 2.0], 0.4),
            gamma: [2.2, 2.3, 2.1],
            mixing: [[0.93, 0.06, 0.01], [0.03, 0.94, 0.03], [0.01, 0.04, 0.95]],
            black: [0.002, 0.002, 0.003],
            vignetting: 0.12,
            defocus_px: 0.0,
            white_boost: 0.0,
            lcd_crosstalk: None,
        },
        surface: Surface::Plane {
            distance: 2.0,
            tilt_deg: [0.0, 0.0],
        },
        albedo: Albedo::Uniform {
            rgb: [0.86, 0.85, 0.82],
        },
        ambient: Ambient::default(),
        specular: None,
        glare: None,
        interreflection: None,
        subsurface: None,
        latency: Latency::default(),
        drift: None,
        more_projectors: Vec::new(),
    }
}

/// A light, colourful texture (paper, fabric): compensable almost everywhere.
fn light_texture() -> Albedo {
    Albedo::Texture {
        palette: vec![
            [0.85, 0.80, 0.65],
            [0.55, 0.70, 0.85],
            [0.85, 0.55, 0.50],
            [0.60, 0.80, 0.55],
            [0.80, 0.75, 0.80],
        ],
        scale: 0.25,
        shade: 0.35,
        sharpness: 2.0,
    }
}
