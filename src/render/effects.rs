//! The effects a scene calls for, and the once-per-render choice of an integrator compiled for exactly them.
//!
//! Each effect is a type-level flag; `select` walks the seven flags once and returns a function pointer
//! to the path tracer monomorphised for that set, so the hot loop holds no code for absent effects.

use std::marker::PhantomData;

/// Which effects a render simulates. Derived from the scene (`Scene::effects`), or forced (e.g. `ALL`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct EffectSet {
    /// Glass: transmission through dielectrics.
    pub refraction: bool,
    /// Specular reflection: mirrors, glass and plastic coats.
    pub reflection: bool,
    /// Microfacet (GGX) reflection of rough conductors.
    pub rough_reflection: bool,
    /// Non-constant textures (texture coordinates are computed at every hit).
    pub textures: bool,
    /// More than one light to choose from (including the environment).
    pub several_lights: bool,
    /// A constant environment seen by escaping rays and sampled as a light.
    pub environment: bool,
    /// A thin lens (aperture > 0).
    pub depth_of_field: bool,
}

impl EffectSet {
    pub const ALL: EffectSet = EffectSet {
        refraction: true,
        reflection: true,
        rough_reflection: true,
        textures: true,
        several_lights: true,
        environment: true,
        depth_of_field: true,
    };

    /// Names of the effects that are on, for logs.
    pub fn names(&self) -> Vec<&'static str> {
        [
            (self.refraction, "refraction"),
            (self.reflection, "reflection"),
            (self.rough_reflection, "rough_reflection"),
            (self.textures, "textures"),
            (self.several_lights, "several_lights"),
            (self.environment, "environment"),
            (self.depth_of_field, "depth_of_field"),
        ]
        .into_iter()
        .filter_map(|(on, name)| on.then_some(name))
        .collect()
    }

    /// Whether every effect of `other` is also in `self`.
    pub fn covers(&self, other: &EffectSet) -> bool {
        (self.refraction || !other.refraction)
            && (self.reflection || !other.reflection)
            && (self.rough_reflection || !other.rough_reflection)
            && (self.textures || !other.textures)
            && (self.several_lights || !other.several_lights)
            && (self.environment || !other.environment)
            && (self.depth_of_field || !other.depth_of_field)
    }
}

/// Compile-time effect set: the integrator is generic over it.
pub trait Effects: 'static {
    const REFRACTION: bool;
    const REFLECTION: bool;
    const ROUGH: bool;
    const TEXTURES: bool;
    const SEVERAL_LIGHTS: bool;
    const ENVIRONMENT: bool;
    const DOF: bool;
}

pub trait Flag: 'static {
    const ON: bool;
}

pub struct On;
pub struct Off;

impl Flag for On {
    const ON: bool = true;
}

impl Flag for Off {
    const ON: bool = false;
}

/// The effect set as a type: one flag per effect, in `EffectSet`'s field order.
pub struct Fx<R, M, G, T, L, E, D>(PhantomData<(R, M, G, T, L, E, D)>);

impl<R: Flag, M: Flag, G: Flag, T: Flag, L: Flag, E: Flag, D: Flag> Effects
    for Fx<R, M, G, T, L, E, D>
{
    const REFRACTION: bool = R::ON;
    const REFLECTION: bool = M::ON;
    const ROUGH: bool = G::ON;
    const TEXTURES: bool = T::ON;
    const SEVERAL_LIGHTS: bool = L::ON;
    const ENVIRONMENT: bool = E::ON;
    const DOF: bool = D::ON;
}

/// Something generic over an effect set, asked for one instance at run time.
pub trait Select {
    type Out;
    fn get<E: Effects>() -> Self::Out;
}

/// Instantiates `S::get` for the type matching `set`: one branch per effect, once per render.
pub fn select<S: Select>(set: EffectSet) -> S::Out {
    fn r<S: Select>(s: EffectSet) -> S::Out {
        if s.refraction {
            m::<S, On>(s)
        } else {
            m::<S, Off>(s)
        }
    }
    fn m<S: Select, R: Flag>(s: EffectSet) -> S::Out {
        if s.reflection {
            g::<S, R, On>(s)
        } else {
            g::<S, R, Off>(s)
        }
    }
    fn g<S: Select, R: Flag, M: Flag>(s: EffectSet) -> S::Out {
        if s.rough_reflection {
            t::<S, R, M, On>(s)
        } else {
            t::<S, R, M, Off>(s)
        }
    }
    fn t<S: Select, R: Flag, M: Flag, G: Flag>(s: EffectSet) -> S::Out {
        if s.textures {
            l::<S, R, M, G, On>(s)
        } else {
            l::<S, R, M, G, Off>(s)
        }
    }
    fn l<S: Select, R: Flag, M: Flag, G: Flag, T: Flag>(s: EffectSet) -> S::Out {
        if s.several_lights {
            e::<S, R, M, G, T, On>(s)
        } else {
            e::<S, R, M, G, T, Off>(s)
        }
    }
    fn e<S: Select, R: Flag, M: Flag, G: Flag, T: Flag, L: Flag>(s: EffectSet) -> S::Out {
        if s.environment {
            d::<S, R, M, G, T, L, On>(s)
        } else {
            d::<S, R, M, G, T, L, Off>(s)
        }
    }
    fn d<S: Select, R: Flag, M: Flag, G: Flag, T: Flag, L: Flag, E: Flag>(s: EffectSet) -> S::Out {
        if s.depth_of_field {
            S::get::<Fx<R, M, G, T, L, E, On>>()
        } else {
            S::get::<Fx<R, M, G, T, L, E, Off>>()
        }
    }
    r::<S>(set)
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Bits;

    impl Select for Bits {
        type Out = [bool; 7];
        fn get<E: Effects>() -> [bool; 7] {
            [
                E::REFRACTION,
                E::REFLECTION,
                E::ROUGH,
                E::TEXTURES,
                E::SEVERAL_LIGHTS,
                E::ENVIRONMENT,
                E::DOF,
            ]
        }
    }

    #[test]
    fn select_maps_each_flag_to_its_constant() {
        let set = EffectSet {
            reflection: true,
            textures: true,
            depth_of_field: true,
            ..Default::default()
        };
        assert_eq!(
            select::<Bits>(set),
            [false, true, false, true, false, false, true]
        );
        assert_eq!(select::<Bits>(EffectSet::ALL), [true; 7]);
        assert!(EffectSet::ALL.covers(&set) && !set.covers(&EffectSet::ALL));
    }
}
