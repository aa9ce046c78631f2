//! Animation: objects that move over time, and the frame clock of the `[animation]` table.
//!
//! An animated object keeps its static placement (`world_from_object`) and adds a motion applied
//! after it, in world space: `world_from_object_at(t) = animation.transform_at(t) ·
//! world_from_object`. Keyframes interpolate translation and scale linearly and rotation by
//! quaternion slerp (Shoemake 1985, "Animating rotation with quaternion curves"), which takes
//! the shorter arc, so two keys 180° or more apart need a key between them.

use std::ops::Range;

use glam::{Mat4, Quat, Vec3};

use super::{Object, Scene};

/// How an object moves. The motion is applied after the object's static placement.
#[derive(Clone, Debug, PartialEq)]
pub enum Animation {
    /// Piecewise-linear keyframes, strictly increasing times (seconds); clamped outside.
    Keyframes(Vec<Keyframe>),
    /// A circle in the xz plane (world axes) through the object's rest position: at time `t` the
    /// object is moved by `radius · (cos θ − cos phase, 0, sin θ − sin phase)`, with
    /// `θ = phase + 2π t / period`. `period` (seconds) must be > 0.
    Orbit { radius: f32, period: f32, phase: f32 },
}

/// One key of [`Animation::Keyframes`]: the transform `T · R · S` at `time` (scale first, then
/// rotate, then translate, as the static placement).
#[derive(Clone, Debug, PartialEq)]
pub struct Keyframe {
    /// Seconds.
    pub time: f32,
    pub translation: Vec3,
    /// A unit quaternion.
    pub rotation: Quat,
    /// Per axis, every factor > 0.
    pub scale: Vec3,
}

/// The `[animation]` table: the frame clock.
#[derive(Clone, Debug, PartialEq)]
pub struct AnimationSettings {
    /// Frames per second, finite and > 0.
    pub fps: f32,
    /// The frames to render, `start..end` with `end > start`; frame `n` is at `n / fps` seconds.
    pub frames: Range<u32>,
}

impl Keyframe {
    pub fn matrix(&self) -> Mat4 {
        Mat4::from_scale_rotation_translation(self.scale, self.rotation, self.translation)
    }
}

impl Animation {
    /// The animated part alone at `time` seconds (without the static placement). An empty
    /// keyframe list is the identity.
    pub fn transform_at(&self, time: f32) -> Mat4 {
        match self {
            Animation::Keyframes(keys) => {
                // First key later than `time`: keys[i - 1] <= time < keys[i].
                let i = keys.partition_point(|k| k.time <= time);
                match (i.checked_sub(1).and_then(|j| keys.get(j)), keys.get(i)) {
                    (None, None) => Mat4::IDENTITY,
                    (Some(a), None) => a.matrix(),
                    (None, Some(b)) => b.matrix(),
                    (Some(a), Some(b)) => {
                        let s = (time - a.time) / (b.time - a.time);
                        Mat4::from_scale_rotation_translation(
                            a.scale.lerp(b.scale, s),
                            a.rotation.slerp(b.rotation, s),
                            a.translation.lerp(b.translation, s),
                        )
                    }
                }
            }
            &Animation::Orbit { radius, period, phase } => {
                // Whole turns dropped in f64: `time / period` overflows f32 for tiny periods
                // (1e-40 s gave NaN, and the instances vanished).
                let turns = (f64::from(time) / f64::from(period)).rem_euclid(1.0);
                let theta = phase + (std::f64::consts::TAU * turns) as f32;
                let offset = radius * Vec3::new(theta.cos() - phase.cos(), 0.0, theta.sin() - phase.sin());
                Mat4::from_translation(offset)
            }
        }
    }
}

impl Object {
    /// `animation.transform_at(time) · world_from_object` (the static placement is applied
    /// first); `world_from_object` when not animated.
    pub fn world_from_object_at(&self, time: f32) -> Mat4 {
        match &self.animation {
            Some(a) => a.transform_at(time) * self.world_from_object,
            None => self.world_from_object,
        }
    }

    pub fn is_animated(&self) -> bool {
        self.animation.is_some()
    }
}

impl Scene {
    /// Whether any object is animated.
    pub fn is_animated(&self) -> bool {
        self.objects.iter().any(Object::is_animated)
    }

    /// The time of `frame` in seconds, `frame / fps`; 0 for a scene without `[animation]`.
    pub fn frame_time(&self, frame: u32) -> f32 {
        match &self.animation {
            // In f64: frame numbers above 2^24 are not exact in f32.
            Some(s) => (f64::from(frame) / f64::from(s.fps)) as f32,
            None => 0.0,
        }
    }

    /// A static copy at `time`: every object's transform baked, every animation and the
    /// `[animation]` settings removed, so it equals the scene a static file would give.
    pub fn at_time(&self, time: f32) -> Scene {
        let objects = self
            .objects
            .iter()
            .map(|o| Object {
                mesh: o.mesh,
                world_from_object: o.world_from_object_at(time),
                material: o.material,
                animation: None,
            })
            .collect();
        Scene {
            path: self.path.clone(),
            camera: self.camera.clone(),
            render: self.render,
            environment: self.environment.clone(),
            materials: self.materials.clone(),
            textures: self.textures.clone(),
            meshes: self.meshes.clone(),
            objects,
            animation: None,
            read: self.read.clone(),
        }
    }
}
