//! S11 for bodies (`GridUpdate`, after the grid update): the two-way momentum exchange with the
//! grid at a body's boundary nodes ([`couple_rigid_bodies`]). The nodes within
//! [`COUPLING_SKIN_CELLS`] of the surface are projected with the collision rule of
//! ALGORITHM §2.11 relative to the body's velocity and acceleration fields (choice D5), the
//! body receives what the projection removed, and the exchange is iterated semi-implicitly (at
//! most [`MAX_COUPLING_ITERATIONS`] passes; derivation in the module docs).
use bevy_ecs::prelude::*;
use glam::{DMat3, DVec3, IVec3};

use super::active::{ActiveRigidBodies, RigidInstance};
use super::body::{RigidAcceleration, RigidExchange, RigidVelocity, bounding_radius};
use crate::collision::{project_acceleration, project_velocity};
use crate::config::{BoundaryCondition, MpmConfig};
use crate::distributed::Ranks;
use crate::grid::{GhostCopy, MpmGrid};
use crate::math::{Real, Vec3};
use crate::step::grid_update::collide_node;
use crate::step::schedule::StepContext;

/// Nodes closer to a body's surface than this many cells (φ ≤ ½Δx) are coupled to it: the
/// discrete surface is the node layer nearest to the true one (see the module docs).
pub const COUPLING_SKIN_CELLS: Real = 0.5;

/// Largest number of projection passes of the semi-implicit exchange per body and step.
pub const MAX_COUPLING_ITERATIONS: usize = 8;

/// A grid node inside a body: storage index, world position (unwrapped along periodic axes),
/// offset from the centre, outward normal, mass and its velocity and acceleration after the
/// grid update.
struct BoundaryNode {
    idx: usize,
    /// Whether this rank counts the node (always in one process, [`Ranks::counts_node`]):
    /// only counted nodes enter the exchange sums, which are then summed over the ranks.
    owned: bool,
    x: Vec3,
    r: Vec3,
    n: Vec3,
    m: Real,
    v: Vec3,
    a: Vec3,
}

/// The body's velocity and acceleration fields during the exchange.
#[derive(Clone, Copy, Debug)]
struct BodyMotion {
    v: DVec3,
    w: DVec3,
    a: DVec3,
    alpha: DVec3,
}

impl BodyMotion {
    fn at(&self, r: Vec3) -> (Vec3, Vec3) {
        let (v, w, a, al) = (
            self.v.as_vec3(),
            self.w.as_vec3(),
            self.a.as_vec3(),
            self.alpha.as_vec3(),
        );
        (v + w.cross(r), a + al.cross(r) + w.cross(w.cross(r)))
    }
}

/// Sums of one projection pass.
#[derive(Default)]
struct ExchangeSums {
    jv: DVec3,
    lv: DVec3,
    ja: DVec3,
    la: DVec3,
    mass: f64,
    inertia: DMat3,
}

impl ExchangeSums {
    /// Adds a node's removed momentum `dv` and rate `da` (mass `m`, offset `r`).
    fn add(&mut self, m: f64, r: DVec3, dv: DVec3, da: DVec3) {
        self.jv += dv;
        self.lv += r.cross(dv);
        self.ja += da;
        self.la += r.cross(da);
        self.mass += m;
        self.inertia += m * (DMat3::from_diagonal(DVec3::splat(r.dot(r))) - outer(r, r));
    }

    /// The sums of all ranks, added in rank order (the same on every rank); unchanged in one
    /// process.
    fn across(self, ranks: Option<&Ranks>) -> Self {
        let Some(ranks) = ranks else { return self };
        let mut mine = Vec::with_capacity(22);
        for v in [self.jv, self.lv, self.ja, self.la] {
            mine.extend(v.to_array());
        }
        mine.push(self.mass);
        mine.extend(self.inertia.to_cols_array());
        let s = ranks.sum(&mine);
        let v = |k: usize| DVec3::new(s[k], s[k + 1], s[k + 2]);
        Self {
            jv: v(0),
            lv: v(3),
            ja: v(6),
            la: v(9),
            mass: s[12],
            inertia: DMat3::from_cols_array(&std::array::from_fn(|k| s[13 + k])),
        }
    }
}

/// §2.11 projection of one node relative to the body (velocity, acceleration with D5, friction
/// correction `extra_dt` = (W₁Λ₆ − λ₅)Δt as for the walls). Returns v′, a′.
#[inline]
fn project_node(
    node: &BoundaryNode,
    motion: &BodyMotion,
    bc: BoundaryCondition,
    extra_dt: Real,
) -> (Vec3, Vec3) {
    let (vb, ab) = motion.at(node.r);
    let rel_a = node.a - ab;
    let extra = extra_dt * (-rel_a.dot(node.n)).max(0.0);
    let v = project_velocity(node.v, vb, node.n, bc, extra);
    let a = match bc {
        BoundaryCondition::Sticky => ab,
        _ if v != node.v => ab + project_acceleration(rel_a, node.n, bc, true),
        _ => node.a,
    };
    (v, a)
}

fn exchange_sums(
    nodes: &[BoundaryNode],
    motion: &BodyMotion,
    bc: BoundaryCondition,
    extra_dt: Real,
) -> ExchangeSums {
    let mut s = ExchangeSums::default();
    for node in nodes.iter().filter(|n| n.owned) {
        let (v, a) = project_node(node, motion, bc, extra_dt);
        if v == node.v && a == node.a {
            continue;
        }
        let m = node.m as f64;
        let dv = m * (node.v - v).as_dvec3();
        let da = m * (node.a - a).as_dvec3();
        s.add(m, node.r.as_dvec3(), dv, da);
    }
    s
}

fn outer(a: DVec3, b: DVec3) -> DMat3 {
    DMat3::from_cols(a * b.x, a * b.y, a * b.z)
}

/// The grid nodes with mass inside the body or within [`COUPLING_SKIN_CELLS`] of its surface at
/// its predicted pose, in (i, j, k) order.
fn boundary_nodes(
    grid: &MpmGrid,
    config: &MpmConfig,
    inst: &RigidInstance,
    ranks: Option<&Ranks>,
) -> Vec<BoundaryNode> {
    if grid.block_count() == 0 {
        return Vec::new();
    }
    let layout = grid.layout;
    let (box_lo, box_hi) = (layout.lo, layout.lo + layout.dims - IVec3::ONE);
    let pose = inst.predicted_pose;
    let skin = COUPLING_SKIN_CELLS * layout.dx;
    let rb = bounding_radius(&inst.shape) + skin;
    let c = pose.translation;
    let mut lo = ((c - Vec3::splat(rb) - layout.origin) * layout.inv_dx)
        .floor()
        .as_ivec3();
    let mut hi = ((c + Vec3::splat(rb) - layout.origin) * layout.inv_dx)
        .ceil()
        .as_ivec3();
    let periodic = config.walls.periodic_axes();
    let counts = crate::step::p2g::periodic_counts(config, grid);
    for a in 0..3 {
        if periodic[a] {
            // Visit each distinct node at most once.
            hi[a] = hi[a].min(lo[a] + counts[a] - 1);
        } else {
            lo[a] = lo[a].max(box_lo[a]);
            hi[a] = hi[a].min(box_hi[a]);
        }
    }
    // Nodes beyond a mirror face are reflected copies of interior nodes (§2.11, D18).
    let mirrors = crate::step::p2g::mirror_faces(config, &layout);
    let inv_rot = pose.rotation.inverse();
    let eps = grid.mass_epsilon;
    let mut out = Vec::new();
    for i in lo.x..=hi.x {
        for j in lo.y..=hi.y {
            for k in lo.z..=hi.z {
                let u = IVec3::new(i, j, k);
                if mirrors.iter().any(|f| f.beyond(u[f.axis])) {
                    continue;
                }
                let mut img = u;
                for a in 0..3 {
                    if periodic[a] {
                        img[a] = u[a].rem_euclid(counts[a]);
                    }
                }
                // Nodes of blocks without storage hold no mass.
                let Some(idx) = grid.index(img) else {
                    continue;
                };
                let node = &grid.nodes[idx];
                if node.mass <= eps {
                    continue;
                }
                let x = layout.node_position(u);
                let (phi, n_local) = inst.shape.sdf(inv_rot * (x - c));
                if phi > skin {
                    continue;
                }
                out.push(BoundaryNode {
                    idx,
                    owned: ranks.is_none_or(|r| r.counts_node(&layout, img)),
                    x: layout.node_position(img),
                    r: x - c,
                    n: pose.rotation * n_local,
                    m: node.mass,
                    v: Vec3::from(node.new_velocity),
                    a: Vec3::from(node.new_acceleration),
                });
            }
        }
    }
    out
}

/// S11 for bodies: the momentum exchange with the grid at the body's boundary nodes and the
/// body's new velocity and rates (module docs). Runs after the grid update (walls and static
/// colliders are applied first; walls again on the nodes a body changed).
pub fn couple_rigid_bodies(
    ctx: Res<StepContext>,
    config: Res<MpmConfig>,
    mut active: ResMut<ActiveRigidBodies>,
    mut grid: ResMut<MpmGrid>,
    ranks: Option<Res<Ranks>>,
) {
    // On several ranks each sums the nodes it owns and the sums are added over the ranks, so
    // every rank moves the body alike (ALGORITHM §12).
    let ranks = ranks.as_deref().filter(|r| r.size() > 1);
    let c = ctx.coefficients;
    let extra_dt = (c.w1l6 - c.l5).max(0.0) * c.dt;
    let walls = config.walls;
    let (dmin, dmax) = (config.domain_min, config.domain_max);
    let mut touched = false;
    for inst in &mut active.bodies {
        let nodes = boundary_nodes(&grid, &config, inst, ranks);
        // Whether any rank has boundary nodes (every rank then takes part in the passes).
        let coupled = match ranks {
            Some(r) => r.max(&[f64::from(u8::from(!nodes.is_empty()))])[0] > 0.0,
            None => !nodes.is_empty(),
        };
        let pv = inst.predicted_velocity;
        let pa = inst.predicted_acceleration;
        let predicted = BodyMotion {
            v: pv.linear.as_dvec3(),
            w: pv.angular.as_dvec3(),
            a: pa.linear.as_dvec3(),
            alpha: pa.angular.as_dvec3(),
        };
        let mass = inst.body.mass as f64;
        let rot = inst.predicted_pose.rotation;
        let i_w = inst.body.world_inertia(rot).as_dmat3();
        let inv_i = inst.body.world_inverse_inertia(rot);
        let rb = bounding_radius(&inst.shape) as f64;
        let mut motion = predicted;
        let mut passes = 0u32;
        if coupled {
            for _ in 1..MAX_COUPLING_ITERATIONS {
                let s = exchange_sums(&nodes, &motion, inst.boundary, extra_dt).across(ranks);
                passes += 1;
                if s.mass <= 0.0 {
                    break;
                }
                let denom = mass + s.mass;
                let lhs_inv = (i_w + s.inertia).inverse();
                let next = BodyMotion {
                    v: (mass * predicted.v + s.jv + s.mass * motion.v) / denom,
                    w: lhs_inv * (i_w * predicted.w + s.lv + s.inertia * motion.w),
                    a: (mass * predicted.a + s.ja + s.mass * motion.a) / denom,
                    alpha: lhs_inv * (i_w * predicted.alpha + s.la + s.inertia * motion.alpha),
                };
                let change = (next.v - motion.v).length() + rb * (next.w - motion.w).length();
                let correction =
                    (next.v - predicted.v).length() + rb * (next.w - predicted.w).length();
                motion = next;
                // Converged to 0.1 % of the correction (or below 0.1 µm/s).
                if change <= 1e-3 * correction + 1e-7 {
                    break;
                }
            }
        }
        // Final pass: project against the last iterate and give the body what it removed.
        let mut s = ExchangeSums::default();
        for node in &nodes {
            let (v, a) = project_node(node, &motion, inst.boundary, extra_dt);
            if v == node.v && a == node.a {
                continue;
            }
            if node.owned {
                let m = node.m as f64;
                let dv = m * (node.v - v).as_dvec3();
                let da = m * (node.a - a).as_dvec3();
                s.add(m, node.r.as_dvec3(), dv, da);
            }
            let (mut v, mut a) = (v, a);
            collide_node(node.x, extra_dt, &walls, dmin, dmax, &[], &mut v, &mut a);
            let gn = &mut grid.nodes[node.idx];
            gn.new_velocity = v.into();
            gn.new_acceleration = a.into();
            touched = true;
        }
        let s = if coupled { s.across(ranks) } else { s };
        if coupled {
            passes += 1;
        }
        let inv_m = 1.0 / inst.body.mass;
        let (jv, lv, ja, la) = (
            s.jv.as_vec3(),
            s.lv.as_vec3(),
            s.ja.as_vec3(),
            s.la.as_vec3(),
        );
        inst.new_velocity = RigidVelocity {
            linear: pv.linear + inv_m * jv,
            angular: pv.angular + inv_i * lv,
        };
        inst.new_acceleration = RigidAcceleration {
            linear: pa.linear + inv_m * ja,
            angular: pa.angular + inv_i * la,
        };
        inst.exchange = RigidExchange {
            impulse: jv,
            angular_impulse: lv,
            rate_exchange: ja,
            wall_impulse: Vec3::ZERO,
            contact_mass: s.mass as Real,
            iterations: passes,
        };
    }
    if touched {
        crate::step::p2g::copy_ghosts(&config, &mut grid, GhostCopy::Update);
    }
}
