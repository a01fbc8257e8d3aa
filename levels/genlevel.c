/* ubake-genlevel: synthetic test levels for ubake, written as glTF 2.0
 * (.gltf JSON + external .bin buffer).
 *
 *   ubake-genlevel --all -o DIR            (every level but estate, door_combo, door_chain:
 *                                           made by name only)
 *   ubake-genlevel NAME -o DIR [--param key=value ...] [--name BASE]
 *   ubake-genlevel --list | --help | NAME --help
 *
 * Conventions (docs: levels/README.md, /DESIGN.md §3-4): metres, Y-up,
 * right-handed, counter-clockwise front faces, flat per-face normals (every
 * quad owns its 4 vertices), uint32 indices, one mesh (one primitive) per
 * node. Every surface is built from planar rectangles ("quads"). Lights use
 * KHR_lights_punctual (point: W/sr, directional: W/m^2, shining down the
 * node's local -Z); emission uses emissiveFactor x
 * KHR_materials_emissive_strength; tags are flat `extras` keys.
 *
 * Standalone C11, links only libm. Output is deterministic.
 */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/types.h>

#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

/* ------------------------------------------------------------------------ */
/* Small utilities                                                           */

static const char *g_prog = "ubake-genlevel";

static void die(const char *fmt, ...)
{
    va_list ap;
    fprintf(stderr, "%s: ", g_prog);
    va_start(ap, fmt);
    vfprintf(stderr, fmt, ap);
    va_end(ap);
    fputc('\n', stderr);
    exit(1);
}

static void *xrealloc(void *p, size_t n)
{
    void *q = realloc(p, n ? n : 1);
    if (!q) die("out of memory");
    return q;
}

static void copy_str(char *dst, size_t cap, const char *src)
{
    size_t n = strlen(src);
    if (n >= cap) die("internal: name too long: %s", src);
    memcpy(dst, src, n + 1);
}

typedef struct { double x, y, z; } V3;

static V3 v3(double x, double y, double z) { V3 r = { x, y, z }; return r; }
static V3 vadd(V3 a, V3 b) { return v3(a.x + b.x, a.y + b.y, a.z + b.z); }
static V3 vsub(V3 a, V3 b) { return v3(a.x - b.x, a.y - b.y, a.z - b.z); }
static V3 vscale(V3 a, double s) { return v3(a.x * s, a.y * s, a.z * s); }
static double vdot(V3 a, V3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
static V3 vcross(V3 a, V3 b)
{
    return v3(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}
static V3 vnorm(V3 a)
{
    double l = sqrt(vdot(a, a));
    if (!(l > 0.0)) die("internal: degenerate vector");
    return vscale(a, 1.0 / l);
}
static double vget(V3 a, int i) { return i == 0 ? a.x : (i == 1 ? a.y : a.z); }
static void vset(V3 *a, int i, double v)
{
    if (i == 0) a->x = v; else if (i == 1) a->y = v; else a->z = v;
}
/* Rotation about +Y by angle t (radians), right-handed: +X turns toward -Z.
 * Same convention as a glTF quaternion (0, sin(t/2), 0, cos(t/2)). */
static V3 rot_y(V3 p, double t)
{
    double c = cos(t), s = sin(t);
    return v3(c * p.x + s * p.z, p.y, -s * p.x + c * p.z);
}
static double deg2rad(double d) { return d * M_PI / 180.0; }

/* ------------------------------------------------------------------------ */
/* Scene being built                                                         */

typedef struct {
    char name[64];
    float *pos, *nrm, *uv;
    uint32_t *idx;
    int nv, ni, capv, capi;
    int mat;
} Mesh;

typedef struct {
    char name[64];
    double base[3];
    double emis_strength; /* radiance = (1,1,1) x strength; 0: not emissive */
    double emis_color[3];
} Material;

enum { LIGHT_POINT, LIGHT_DIRECTIONAL };
typedef struct {
    char name[64];
    int type;
    double color[3];
    double intensity;
} Light;

typedef struct { char key[32]; char val[64]; } Extra;

typedef struct {
    char name[64];
    int mesh, light;
    int has_t, has_r;
    double t[3], r[4];
    Extra ex[8];
    int nex;
} Node;

typedef struct {
    Mesh *meshes; int nmesh, capmesh;
    Material *mats; int nmat, capmat;
    Light *lights; int nlight, caplight;
    Node *nodes; int nnode, capnode;
    int has_sky; double sky[3];
} Scene;

static Scene S;

static void scene_reset(void)
{
    for (int i = 0; i < S.nmesh; i++) {
        free(S.meshes[i].pos); free(S.meshes[i].nrm);
        free(S.meshes[i].uv); free(S.meshes[i].idx);
    }
    free(S.meshes); free(S.mats); free(S.lights); free(S.nodes);
    memset(&S, 0, sizeof S);
}

/* Material by name; re-adding the same name returns the existing one. */
static int material(const char *name, double r, double g, double b, double emis)
{
    for (int i = 0; i < S.nmat; i++)
        if (!strcmp(S.mats[i].name, name)) return i;
    if (S.nmat == S.capmat) {
        S.capmat = S.capmat ? 2 * S.capmat : 8;
        S.mats = xrealloc(S.mats, (size_t)S.capmat * sizeof *S.mats);
    }
    Material *m = &S.mats[S.nmat];
    memset(m, 0, sizeof *m);
    copy_str(m->name, sizeof m->name, name);
    m->base[0] = r; m->base[1] = g; m->base[2] = b;
    m->emis_strength = emis;
    m->emis_color[0] = m->emis_color[1] = m->emis_color[2] = 1.0;
    return S.nmat++;
}

static int mesh_new(const char *name, int mat)
{
    if (S.nmesh == S.capmesh) {
        S.capmesh = S.capmesh ? 2 * S.capmesh : 16;
        S.meshes = xrealloc(S.meshes, (size_t)S.capmesh * sizeof *S.meshes);
    }
    Mesh *m = &S.meshes[S.nmesh];
    memset(m, 0, sizeof *m);
    copy_str(m->name, sizeof m->name, name);
    m->mat = mat;
    return S.nmesh++;
}

static Node *node_new(const char *name)
{
    for (int i = 0; i < S.nnode; i++)
        if (!strcmp(S.nodes[i].name, name)) die("internal: duplicate node name %s", name);
    if (S.nnode == S.capnode) {
        S.capnode = S.capnode ? 2 * S.capnode : 16;
        S.nodes = xrealloc(S.nodes, (size_t)S.capnode * sizeof *S.nodes);
    }
    Node *n = &S.nodes[S.nnode++];
    memset(n, 0, sizeof *n);
    copy_str(n->name, sizeof n->name, name);
    n->mesh = -1;
    n->light = -1;
    return n;
}

static void node_extra(Node *n, const char *key, const char *val)
{
    if (n->nex == (int)(sizeof n->ex / sizeof n->ex[0])) die("internal: too many extras");
    copy_str(n->ex[n->nex].key, sizeof n->ex[0].key, key);
    copy_str(n->ex[n->nex].val, sizeof n->ex[0].val, val);
    n->nex++;
}

static void node_translate(Node *n, V3 t)
{
    n->has_t = 1;
    n->t[0] = t.x; n->t[1] = t.y; n->t[2] = t.z;
}

/* A node holding mesh `mesh` (vertices already in world space unless a
 * transform is set afterwards). */
static Node *mesh_node(const char *name, int mesh)
{
    Node *n = node_new(name);
    n->mesh = mesh;
    return n;
}

static Node *light_node(const char *name, int type, double intensity,
                        double r, double g, double b, V3 pos)
{
    if (S.nlight == S.caplight) {
        S.caplight = S.caplight ? 2 * S.caplight : 8;
        S.lights = xrealloc(S.lights, (size_t)S.caplight * sizeof *S.lights);
    }
    Light *l = &S.lights[S.nlight];
    memset(l, 0, sizeof *l);
    copy_str(l->name, sizeof l->name, name);
    l->type = type;
    l->color[0] = r; l->color[1] = g; l->color[2] = b;
    l->intensity = intensity;
    Node *n = node_new(name);
    n->light = S.nlight++;
    node_translate(n, pos);
    return n;
}

/* Set node rotation so that its local -Z axis points along direction d. */
static void node_aim(Node *n, V3 d)
{
    V3 a = v3(0, 0, -1), b = vnorm(d);
    double c = vdot(a, b);
    double q[4];
    if (c < -1.0 + 1e-12) { /* opposite: 180 degrees about +Y */
        q[0] = 0; q[1] = 1; q[2] = 0; q[3] = 0;
    } else {
        V3 x = vcross(a, b);
        q[0] = x.x; q[1] = x.y; q[2] = x.z; q[3] = 1.0 + c;
        double l = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
        for (int i = 0; i < 4; i++) q[i] /= l;
    }
    n->has_r = 1;
    memcpy(n->r, q, sizeof q);
}

/* ------------------------------------------------------------------------ */
/* Geometry: everything is planar rectangles with their own 4 vertices       */

static void mesh_reserve(Mesh *m, int addv, int addi)
{
    if (m->nv + addv > m->capv) {
        while (m->nv + addv > m->capv) m->capv = m->capv ? 2 * m->capv : 64;
        m->pos = xrealloc(m->pos, (size_t)m->capv * 3 * sizeof(float));
        m->nrm = xrealloc(m->nrm, (size_t)m->capv * 3 * sizeof(float));
    }
    if (m->ni + addi > m->capi) {
        while (m->ni + addi > m->capi) m->capi = m->capi ? 2 * m->capi : 96;
        m->idx = xrealloc(m->idx, (size_t)m->capi * sizeof(uint32_t));
    }
}

/* Add the planar quad p[0..3] whose front face points along n_expected.
 * The winding is flipped if needed so that it is counter-clockwise seen from
 * the front; the stored normal is the exact geometric one. */
static void add_face(int mi, const V3 p_in[4], V3 n_expected)
{
    Mesh *m = &S.meshes[mi];
    V3 p[4] = { p_in[0], p_in[1], p_in[2], p_in[3] };
    V3 n = vcross(vsub(p[1], p[0]), vsub(p[2], p[0]));
    if (vdot(n, n_expected) < 0) {
        V3 t = p[1]; p[1] = p[3]; p[3] = t;
        n = vscale(n, -1.0);
    }
    n = vnorm(n);
    if (vdot(n, vnorm(n_expected)) < 0.999) die("internal: face normal mismatch in %s", m->name);
    mesh_reserve(m, 4, 6);
    uint32_t b = (uint32_t)m->nv;
    for (int k = 0; k < 4; k++) {
        float *P = m->pos + 3 * (m->nv + k), *N = m->nrm + 3 * (m->nv + k);
        P[0] = (float)p[k].x; P[1] = (float)p[k].y; P[2] = (float)p[k].z;
        N[0] = (float)n.x; N[1] = (float)n.y; N[2] = (float)n.z;
    }
    m->nv += 4;
    uint32_t t[6] = { b, b + 1, b + 2, b, b + 2, b + 3 };
    memcpy(m->idx + m->ni, t, sizeof t);
    m->ni += 6;
}

/* Raw indexed geometry (hard-case levels only: not quads, so no uv1 grid).
 * mesh_vertex adds one vertex carrying normal n and returns its index;
 * mesh_tri adds one triangle by vertex indices, as given (degenerate triangles
 * have no winding to check). */
static uint32_t mesh_vertex(int mi, V3 p, V3 n)
{
    Mesh *m = &S.meshes[mi];
    mesh_reserve(m, 1, 0);
    float *P = m->pos + 3 * m->nv, *N = m->nrm + 3 * m->nv;
    P[0] = (float)p.x; P[1] = (float)p.y; P[2] = (float)p.z;
    N[0] = (float)n.x; N[1] = (float)n.y; N[2] = (float)n.z;
    return (uint32_t)m->nv++;
}

static void mesh_tri(int mi, uint32_t a, uint32_t b, uint32_t c)
{
    Mesh *m = &S.meshes[mi];
    mesh_reserve(m, 0, 3);
    m->idx[m->ni++] = a; m->idx[m->ni++] = b; m->idx[m->ni++] = c;
}

/* Triangle with its own 3 vertices, wound counter-clockwise about n
 * (non-degenerate input only). */
static void add_tri(int mi, V3 a, V3 b, V3 c, V3 n)
{
    if (vdot(vcross(vsub(b, a), vsub(c, a)), n) < 0) { V3 t = b; b = c; c = t; }
    uint32_t i = mesh_vertex(mi, a, n), j = mesh_vertex(mi, b, n), k = mesh_vertex(mi, c, n);
    mesh_tri(mi, i, j, k);
}

/* Rectangle o + [0,1]eu + [0,1]ev split into nu x nv quads, facing n. */
static void add_grid(int mi, V3 o, V3 eu, V3 ev, int nu, int nv, V3 n)
{
    for (int j = 0; j < nv; j++)
        for (int i = 0; i < nu; i++) {
            V3 a = vadd(o, vadd(vscale(eu, (double)i / nu), vscale(ev, (double)j / nv)));
            V3 bu = vscale(eu, 1.0 / nu), bv = vscale(ev, 1.0 / nv);
            V3 p[4] = { a, vadd(a, bu), vadd(vadd(a, bu), bv), vadd(a, bv) };
            add_face(mi, p, n);
        }
}

/* Axis-aligned rectangle: coordinate `axis` = c; the other two axes span
 * [lo,hi] (given as full V3s, the `axis` component ignored). Faces along
 * +axis if sign > 0, else -axis. Subdivided n x n. */
static void add_rect(int mi, int axis, double c, V3 lo, V3 hi, int sign, int nsub)
{
    int b = (axis + 1) % 3, d = (axis + 2) % 3;
    V3 o = lo, eu = v3(0, 0, 0), ev = v3(0, 0, 0), n = v3(0, 0, 0);
    vset(&o, axis, c);
    vset(&eu, b, vget(hi, b) - vget(lo, b));
    vset(&ev, d, vget(hi, d) - vget(lo, d));
    vset(&n, axis, sign > 0 ? 1.0 : -1.0);
    add_grid(mi, o, eu, ev, nsub, nsub, n);
}

/* Closed box [mn,mx] with outward normals (6 faces), turned by `yaw` radians
 * about the vertical axis through `pivot` (rot_y convention). */
static void add_box_yaw(int mi, V3 mn, V3 mx, double yaw, V3 pivot)
{
    for (int a = 0; a < 3; a++)
        for (int s = 0; s < 2; s++) {
            int b = (a + 1) % 3, c = (a + 2) % 3;
            V3 p[4], n = v3(0, 0, 0);
            for (int k = 0; k < 4; k++) {
                V3 q = mn;
                vset(&q, a, s ? vget(mx, a) : vget(mn, a));
                vset(&q, b, (k == 1 || k == 2) ? vget(mx, b) : vget(mn, b));
                vset(&q, c, (k >= 2) ? vget(mx, c) : vget(mn, c));
                p[k] = vadd(rot_y(vsub(q, pivot), yaw), pivot);
            }
            vset(&n, a, s ? 1.0 : -1.0);
            add_face(mi, p, rot_y(n, yaw));
        }
}

static void add_box(int mi, V3 mn, V3 mx) { add_box_yaw(mi, mn, mx, 0.0, v3(0, 0, 0)); }

/* One node with one closed axis-aligned box. */
static void box_node(const char *name, int mat, V3 mn, V3 mx)
{
    int m = mesh_new(name, mat);
    add_box(m, mn, mx);
    mesh_node(name, m);
}

/* ------------------------------------------------------------------------ */
/* Parameters                                                                */

#define MAXP 16
typedef struct {
    const char *key;
    int n;          /* components: 1 or 3 */
    double def[3];
    const char *help;
} ParamDef;

typedef struct {
    const char *name;
    const char *purpose;
    void (*build)(void);
    ParamDef p[MAXP];
} LevelDef;

/* Parameters every level accepts. */
static const ParamDef common_params[] = {
    { "uv1", 1, { 0 }, "1: write TEXCOORD_1 (and the same accessor as TEXCOORD_0): one grid cell per quad in a single atlas" },
    { "uv1_res", 1, { 64 }, "atlas resolution in texels used to lay out the uv1 grid" },
    { "uv1_pad", 1, { 4 }, "texels of padding between uv1 rectangles and around the atlas border" },
    { "texel_size", 1, { 0 }, ">0: write scene extras ubake_texel_size (m per texel)" },
    { "glg_spacing", 1, { 0 }, ">0: write scene extras ubake_glg_spacing (m)" },
    { "llg_prop", 1, { 0 }, "1: add a box node llg_prop tagged ubake_receiver llg (albedo 0.6)" },
    { "llg_prop_at", 3, { 0, 0, 0 }, "llg_prop: centre of its bottom face, m" },
    { "llg_prop_size", 3, { 0.4, 0.4, 0.4 }, "llg_prop: box size x, y, z, m" },
    { "lights_dls", 1, { 0 }, "1: every light without a set joins dynamic light set \"lights\"" },
};
#define NCOMMON ((int)(sizeof common_params / sizeof common_params[0]))

static const LevelDef *g_level;
static double g_val[MAXP + NCOMMON][3];
static int g_set[MAXP + NCOMMON];

static int level_nparams(const LevelDef *L)
{
    int n = 0;
    while (n < MAXP && L->p[n].key) n++;
    return n;
}

static const ParamDef *param_def(const LevelDef *L, int i)
{
    int n = level_nparams(L);
    return i < n ? &L->p[i] : &common_params[i - n];
}

static int param_index(const LevelDef *L, const char *key)
{
    int n = level_nparams(L) + NCOMMON;
    for (int i = 0; i < n; i++)
        if (!strcmp(param_def(L, i)->key, key)) return i;
    return -1;
}

static const double *pv(const char *key)
{
    int i = param_index(g_level, key);
    if (i < 0) die("internal: level %s has no param %s", g_level->name, key);
    return g_val[i];
}
static double P(const char *key) { return pv(key)[0]; }
static int PI_(const char *key) { return (int)lround(P(key)); }

static void params_defaults(const LevelDef *L)
{
    int n = level_nparams(L) + NCOMMON;
    for (int i = 0; i < n; i++) {
        memcpy(g_val[i], param_def(L, i)->def, sizeof g_val[i]);
        g_set[i] = 0;
    }
}

static void params_set(const LevelDef *L, const char *kv)
{
    const char *eq = strchr(kv, '=');
    if (!eq || eq == kv) die("bad --param '%s' (want key=value)", kv);
    char key[64];
    size_t kl = (size_t)(eq - kv);
    if (kl >= sizeof key) die("bad --param '%s' (key too long)", kv);
    memcpy(key, kv, kl);
    key[kl] = 0;
    int i = param_index(L, key);
    if (i < 0) die("level %s has no parameter '%s' (see %s %s --help)", L->name, key, g_prog, L->name);
    const ParamDef *d = param_def(L, i);
    const char *s = eq + 1;
    for (int c = 0; c < d->n; c++) {
        char *end;
        errno = 0;
        double v = strtod(s, &end);
        if (end == s || errno || !isfinite(v))
            die("bad value for %s: '%s' (want %d number%s)", key, eq + 1, d->n, d->n > 1 ? "s, comma-separated" : "");
        g_val[i][c] = v;
        s = end;
        if (c + 1 < d->n) {
            if (*s != ',') die("bad value for %s: '%s' (want %d comma-separated numbers)", key, eq + 1, d->n);
            s++;
        }
    }
    if (*s) die("bad value for %s: '%s' (trailing characters)", key, eq + 1);
    g_set[i] = 1;
}

static void require(int ok, const char *what)
{
    if (!ok) die("level %s: invalid parameters: %s", g_level->name, what);
}

/* ------------------------------------------------------------------------ */
/* Levels                                                                    */

/* cornell: 2 m Cornell box, x,z in [-1,1], y in [0,2], inward single-sided
 * quads, two white closed boxes, point light or emissive ceiling patch. */
static void build_cornell(void)
{
    int open = PI_("open"), emissive = PI_("emissive"), lamps = PI_("lamps");
    double I = P("light"), ly = P("light_y"), le = P("le"), ps = P("patch"), lle = P("lamp_le");
    require(I >= 0 && le >= 0 && ps > 0 && ps < 2 && ly > 0 && ly < 2 && lamps >= 0 && lamps <= 4 && lle >= 0,
            "light>=0, le>=0, 0<patch<2, 0<light_y<2, 0<=lamps<=4, lamp_le>=0");
    int white = material("white", 0.73, 0.73, 0.73, 0);
    int red = material("red", 0.63, 0.065, 0.05, 0);
    int green = material("green", 0.14, 0.45, 0.091, 0);
    int m;
    m = mesh_new("floor", white);
    add_rect(m, 1, 0.0, v3(-1, 0, -1), v3(1, 0, 1), +1, 1);
    mesh_node("floor", m);
    m = mesh_new("ceiling", white);
    add_rect(m, 1, 2.0, v3(-1, 0, -1), v3(1, 0, 1), -1, 1);
    mesh_node("ceiling", m);
    m = mesh_new("back_wall", white);
    add_rect(m, 2, -1.0, v3(-1, 0, 0), v3(1, 2, 0), +1, 1);
    mesh_node("back_wall", m);
    m = mesh_new("left_wall", red);
    add_rect(m, 0, -1.0, v3(0, 0, -1), v3(0, 2, 1), +1, 1);
    mesh_node("left_wall", m);
    m = mesh_new("right_wall", green);
    add_rect(m, 0, 1.0, v3(0, 0, -1), v3(0, 2, 1), -1, 1);
    mesh_node("right_wall", m);
    if (!open) {
        m = mesh_new("front_wall", white);
        add_rect(m, 2, 1.0, v3(-1, 0, 0), v3(1, 2, 0), -1, 1);
        mesh_node("front_wall", m);
    }
    /* Short box: 0.6 m cube at the front right; tall box: 0.6x1.2x0.6 at
     * the back left (the classic layout mapped to this frame). */
    V3 sc = v3(0.33, 0.0, 0.39), tc = v3(-0.33, 0.0, -0.27);
    m = mesh_new("short_box", white);
    add_box_yaw(m, v3(sc.x - 0.3, 0, sc.z - 0.3), v3(sc.x + 0.3, 0.6, sc.z + 0.3), deg2rad(-18), sc);
    mesh_node("short_box", m);
    m = mesh_new("tall_box", white);
    add_box_yaw(m, v3(tc.x - 0.3, 0, tc.z - 0.3), v3(tc.x + 0.3, 1.2, tc.z + 0.3), deg2rad(18), tc);
    mesh_node("tall_box", m);
    if (emissive) {
        int em = material("emitter", 0.73, 0.73, 0.73, le);
        m = mesh_new("light_patch", em);
        double h = 0.5 * ps;
        add_rect(m, 1, 1.999, v3(-h, 0, -h), v3(h, 0, h), -1, 1);
        mesh_node("light_patch", m);
    } else {
        Node *n = light_node("light", LIGHT_POINT, I, 1, 1, 1, v3(0, ly, 0));
        node_extra(n, "ubake_light", "static");
    }
    /* Small dim wall lamps low down (0.12 m square, 25 cm up): beside the ceiling patch's
     * power each is a fixture a power-proportional pick hardly ever chooses (oa_dm4's
     * skull lights beside its iron crosses). Left, right, back (twice) walls. */
    if (lamps > 0) {
        int lm_ = material("wall_lamp", 0.73, 0.73, 0.73, lle);
        const double a = 0.06, y0 = 0.19, y1 = 0.31;
        for (int k = 0; k < lamps; k++) {
            char nm[32];
            snprintf(nm, sizeof nm, "wall_lamp_%d", k);
            m = mesh_new(nm, lm_);
            if (k == 0) add_rect(m, 0, -0.999, v3(0, y0, 0.5 - a), v3(0, y1, 0.5 + a), +1, 1);
            else if (k == 1) add_rect(m, 0, 0.999, v3(0, y0, -0.5 - a), v3(0, y1, -0.5 + a), -1, 1);
            else add_rect(m, 2, -0.999, v3((k == 2 ? 0.6 : -0.6) - a, y0, 0), v3((k == 2 ? 0.6 : -0.6) + a, y1, 0), +1, 1);
            mesh_node(nm, m);
        }
    }
}

/* furnace: closed 2 m cube (x,z in [-1,1], y in [0,2]), inward faces,
 * uniform albedo rho and emission Le everywhere. */
static void build_furnace(void)
{
    double rho = P("rho"), le = P("le"), sz = P("size");
    int n = PI_("n");
    require(rho >= 0 && rho <= 1 && le >= 0 && n >= 1 && n <= 64 && sz > 0, "0<=rho<=1, le>=0, 1<=n<=64, size>0");
    int mat = material("furnace", rho, rho, rho, le);
    double h = 0.5 * sz;
    static const char *names[6] = { "furnace_wall_xneg", "furnace_wall_xpos", "furnace_floor",
                                    "furnace_ceiling", "furnace_wall_zneg", "furnace_wall_zpos" };
    for (int a = 0; a < 3; a++)
        for (int s = 0; s < 2; s++) {
            const char *nm = names[2 * a + s];
            int m = mesh_new(nm, mat);
            V3 lo = v3(-h, 0, -h), hi = v3(h, sz, h);
            double c = s ? vget(hi, a) : vget(lo, a);
            add_rect(m, a, c, lo, hi, s ? -1 : +1, n); /* inward */
            mesh_node(nm, m);
        }
}

/* plane_point: black 20x20 plane at y=0 facing +y, point light above origin. */
static void build_plane_point(void)
{
    double h = P("h"), I = P("intensity"), sz = P("size");
    int n = PI_("n");
    require(h > 0 && I >= 0 && sz > 0 && n >= 1 && n <= 256, "h>0, intensity>=0, size>0, 1<=n<=256");
    int mat = material("black", 0, 0, 0, 0);
    int m = mesh_new("plane", mat);
    add_rect(m, 1, 0.0, v3(-sz / 2, 0, -sz / 2), v3(sz / 2, 0, sz / 2), +1, n);
    mesh_node("plane", m);
    Node *l = light_node("light", LIGHT_POINT, I, 1, 1, 1, v3(0, h, 0));
    node_extra(l, "ubake_light", "static");
}

/* sky_plane: the same black plane lit only by a constant sky. */
static void build_sky_plane(void)
{
    double sz = P("size");
    const double *sky = pv("sky");
    int n = PI_("n");
    require(sz > 0 && n >= 1 && n <= 256 && sky[0] >= 0 && sky[1] >= 0 && sky[2] >= 0, "size>0, 1<=n<=256, sky>=0");
    int mat = material("black", 0, 0, 0, 0);
    int m = mesh_new("plane", mat);
    add_rect(m, 1, 0.0, v3(-sz / 2, 0, -sz / 2), v3(sz / 2, 0, sz / 2), +1, n);
    mesh_node("plane", m);
    S.has_sky = 1;
    memcpy(S.sky, sky, sizeof S.sky);
}

/* two_rooms: rooms A (x<0) and B (x>0), 4x3x4 m interiors, sharing one closed
 * wall of thickness t centred on x=0. All other walls: closed slabs. */
static void build_two_rooms(void)
{
    double t = P("t"), w = P("wall"), alb = P("albedo"), I = P("intensity"), ly = P("light_y");
    require(t > 0 && t < 1 && w > 0 && alb >= 0 && alb < 1 && I >= 0 && ly > 0 && ly < 3,
            "0<t<1, wall>0, 0<=albedo<1, intensity>=0, 0<light_y<3");
    int mat = material("grey", alb, alb, alb, 0);
    double ht = 0.5 * t;
    double xa0 = -4.0 - ht, xa1 = -ht; /* room A interior */
    double xb0 = ht, xb1 = 4.0 + ht;   /* room B interior */
    const double H = 3.0, Z = 2.0;
    box_node("shared_wall", mat, v3(-ht, 0, -Z), v3(ht, H, Z));
    /* Room A */
    box_node("room_a_floor", mat, v3(xa0 - w, -w, -Z - w), v3(0, 0, Z + w));
    box_node("room_a_ceiling", mat, v3(xa0 - w, H, -Z - w), v3(0, H + w, Z + w));
    box_node("room_a_wall_west", mat, v3(xa0 - w, 0, -Z - w), v3(xa0, H, Z + w));
    box_node("room_a_wall_north", mat, v3(xa0, 0, -Z - w), v3(0, H, -Z));
    box_node("room_a_wall_south", mat, v3(xa0, 0, Z), v3(0, H, Z + w));
    /* Room B */
    box_node("room_b_floor", mat, v3(0, -w, -Z - w), v3(xb1 + w, 0, Z + w));
    box_node("room_b_ceiling", mat, v3(0, H, -Z - w), v3(xb1 + w, H + w, Z + w));
    box_node("room_b_wall_east", mat, v3(xb1, 0, -Z - w), v3(xb1 + w, H, Z + w));
    box_node("room_b_wall_north", mat, v3(0, 0, -Z - w), v3(xb1, H, -Z));
    box_node("room_b_wall_south", mat, v3(0, 0, Z), v3(xb1, H, Z + w));
    (void)xa1; (void)xb0;
    Node *l = light_node("light_a", LIGHT_POINT, I, 1, 1, 1, v3(0.5 * (xa0 + xa1), ly, 0));
    node_extra(l, "ubake_light", "static");
}

/* sunroom: 5x3x5 m room with a 1x2 m doorway in the south (+z) wall, ground
 * plane outside, sun through the doorway, optional door leaf. The doorway's size, sill
 * and the open pose's angle are arguments, so the door regression levels share it. */
static void sunroom_build(double DW, double DH, double sill, double open_deg)
{
    int door = PI_("door");
    double w = P("wall"), alb = P("albedo"), galb = P("ground_albedo"), E = P("sun");
    double el = P("elev"), az = P("azim"), gs = P("ground");
    const double *sky = pv("sky");
    require(w > 0 && alb >= 0 && alb < 1 && galb >= 0 && galb < 1 && E >= 0 && el > 0 && el <= 90 &&
            gs > 6 && sky[0] >= 0 && sky[1] >= 0 && sky[2] >= 0,
            "wall>0, 0<=albedo<1, 0<=ground_albedo<1, sun>=0, 0<elev<=90, ground>6, sky>=0");
    int wm = material("wall", alb, alb, alb, 0);
    int gm = material("ground", galb, galb, galb, 0);
    const double R = 2.5, H = 3.0;
    double o = R + w; /* outer half-extent */
    box_node("floor", wm, v3(-o, -w, -o), v3(o, 0, o));
    box_node("ceiling", wm, v3(-o, H, -o), v3(o, H + w, o));
    box_node("wall_north", wm, v3(-o, 0, -o), v3(o, H, -R));
    box_node("wall_west", wm, v3(-o, 0, -R), v3(-R, H, R));
    box_node("wall_east", wm, v3(R, 0, -R), v3(o, H, R));
    box_node("wall_south_west", wm, v3(-o, 0, R), v3(-DW, H, o));
    box_node("wall_south_east", wm, v3(DW, 0, R), v3(o, H, o));
    box_node("wall_south_lintel", wm, v3(-DW, sill + DH, R), v3(DW, H, o));
    if (sill > 0)
        box_node("wall_south_sill", wm, v3(-DW, 0, R), v3(DW, sill, o));
    /* Ground: y=0, [-g/2,g/2]^2 minus the building footprint [-o,o]^2. */
    double g = 0.5 * gs;
    int m = mesh_new("ground", gm);
    add_rect(m, 1, 0.0, v3(-g, 0, o), v3(g, 0, g), +1, 1);
    add_rect(m, 1, 0.0, v3(-g, 0, -g), v3(g, 0, -o), +1, 1);
    add_rect(m, 1, 0.0, v3(-g, 0, -o), v3(-o, 0, o), +1, 1);
    add_rect(m, 1, 0.0, v3(o, 0, -o), v3(g, 0, o), +1, 1);
    mesh_node("ground", m);
    if (door) {
        const double DT = 0.05;
        int dm = material("door", 0.5, 0.5, 0.5, 0);
        int lm = mesh_new("door_leaf", dm);
        /* Local frame: hinge axis = local +Y through the origin. */
        add_box(lm, v3(0, 0, 0), v3(2 * DW, DH, DT));
        Node *c = mesh_node("door_closed", lm);
        node_translate(c, v3(-DW, sill, R));
        node_extra(c, "ubake_door", "front");
        Node *op = mesh_node("door_open", lm);
        node_translate(op, v3(-DW, sill, R));
        double ha = 0.5 * deg2rad(open_deg);
        op->has_r = 1;
        op->r[0] = 0; op->r[1] = sin(ha); op->r[2] = 0; op->r[3] = cos(ha);
        node_extra(op, "ubake_door_open", "front");
    }
    double e = deg2rad(el), a = deg2rad(az);
    V3 to_sun = v3(sin(a) * cos(e), sin(e), cos(a) * cos(e));
    Node *sn = light_node("sun", LIGHT_DIRECTIONAL, E, 1, 1, 1, vscale(to_sun, 10.0));
    node_aim(sn, vscale(to_sun, -1.0));
    node_extra(sn, "ubake_light", "static");
    S.has_sky = 1;
    memcpy(S.sky, sky, sizeof S.sky);
}

static void build_sunroom(void) { sunroom_build(0.5, 2.0, 0.0, 90.0); }

/* door_small: the sunroom with a 10 cm square hatch 1.5 m up instead of the doorway: a
 * tiny portal, sun through it lands far from the wall (door regression suite). */
static void build_door_small(void) { sunroom_build(0.05, 0.1, 1.5, 90.0); }

/* door_grazing: the sunroom whose open pose lies 10 degrees off the inner south wall,
 * with a low sun from the side: light grazes the wall and the open leaf. */
static void build_door_grazing(void) { sunroom_build(0.5, 2.0, 0.0, 170.0); }

/* door_rooms: two 4x3x4 m rooms joined by a 1x2 m door in the shared wall (x=0), a lamp
 * in room A (x<0), room B dark until the door opens; the open pose swings into B.
 * door_rooms_build is shared with door_combo: leaf albedo, lamp A's place, an optional
 * DLS lamp in room B and the door's ubake_combine tag are arguments (door_rooms passes
 * the values it always had). */
static void door_rooms_build(double leaf_alb, V3 lamp_a, double lamp_b, V3 lamp_b_at,
                             const char *combine, int black_leaf)
{
    double w = P("wall"), alb = P("albedo"), I = P("intensity"), t = P("t");
    require(w > 0 && alb >= 0 && alb < 1 && I >= 0 && t > 0.06 && t < 1,
            "wall>0, 0<=albedo<1, intensity>=0, 0.06<t<1");
    require(leaf_alb >= 0 && leaf_alb < 1 && lamp_b >= 0, "0<=leaf_albedo<1, lamp_b>=0");
    int mat = material("grey", alb, alb, alb, 0);
    const double H = 3.0, Z = 2.0, X = 4.0, DW = 0.5, DH = 2.0, DT = 0.05;
    double ht = 0.5 * t;
    box_node("floor", mat, v3(-X - ht - w, -w, -Z - w), v3(X + ht + w, 0, Z + w));
    box_node("ceiling", mat, v3(-X - ht - w, H, -Z - w), v3(X + ht + w, H + w, Z + w));
    box_node("wall_west", mat, v3(-X - ht - w, 0, -Z), v3(-X - ht, H, Z));
    box_node("wall_east", mat, v3(X + ht, 0, -Z), v3(X + ht + w, H, Z));
    box_node("wall_north", mat, v3(-X - ht - w, 0, -Z - w), v3(X + ht + w, H, -Z));
    box_node("wall_south", mat, v3(-X - ht - w, 0, Z), v3(X + ht + w, H, Z + w));
    box_node("shared_north", mat, v3(-ht, 0, -Z), v3(ht, H, -DW));
    box_node("shared_south", mat, v3(-ht, 0, DW), v3(ht, H, Z));
    box_node("shared_lintel", mat, v3(-ht, DH, -DW), v3(ht, H, DW));
    int dm = material("door", leaf_alb, leaf_alb, leaf_alb, 0);
    int lm = mesh_new("door_leaf", dm);
    add_box(lm, v3(0, 0, 0), v3(DT, DH, 2 * DW));
    Node *c = mesh_node("door_closed", lm);
    node_translate(c, v3(-0.5 * DT, 0, -DW));
    node_extra(c, "ubake_door", "middle");
    if (combine)
        node_extra(c, "ubake_combine", combine);
    if (black_leaf)
        node_extra(c, "ubake_receiver", "none");
    Node *op = mesh_node("door_open", lm);
    node_translate(op, v3(-0.5 * DT, 0, -DW));
    op->has_r = 1;
    op->r[0] = 0; op->r[1] = sin(M_PI / 4); op->r[2] = 0; op->r[3] = cos(M_PI / 4);
    node_extra(op, "ubake_door_open", "middle");
    Node *l = light_node("lamp_a", LIGHT_POINT, I, 1, 1, 1, lamp_a);
    node_extra(l, "ubake_light", "static");
    if (lamp_b > 0) {
        Node *b = light_node("lamp_b", LIGHT_POINT, lamp_b, 1, 1, 1, lamp_b_at);
        node_extra(b, "ubake_light", "static");
        node_extra(b, "ubake_dls", "lamp_b");
    }
}

static void build_door_rooms(void)
{
    door_rooms_build(0.5, v3(-2.0, 2.0, 0.5), 0.0, v3(0, 0, 0), NULL, 0);
}

/* door_combo: door_rooms with a light-coloured leaf, lamp A (static) and a DLS lamp
 * lamp_b in room B, and the door tagged `ubake_combine: lamp_b` (door x set combination).
 * combine=0 leaves the tag out; lamp_b=0 the set; black_leaf=1 tags the closed leaf
 * `ubake_receiver: none`, which keeps it black in the base (the bake before S_C). */
static void build_door_combo(void)
{
    const double *a = pv("lamp_a_at"), *b = pv("lamp_b_at");
    door_rooms_build(P("leaf_albedo"), v3(a[0], a[1], a[2]), P("lamp_b"), v3(b[0], b[1], b[2]),
                     PI_("combine") ? "lamp_b" : NULL, PI_("black_leaf"));
}

/* door_chain: three 3x3x4 m rooms A | B | C along x joined by doors "ab" (x=-1.5) and
 * "bc" (x=+1.5) in line, lamp in A: room C sees the lamp only with both doors open, the
 * door x door case. Leaves 0.5 albedo, open poses swing 90 degrees into B and C; "bc"
 * carries ubake_combine: ab (combine=0: untagged). */
static void build_door_chain(void)
{
    double w = P("wall"), alb = P("albedo"), I = P("intensity"), t = P("t");
    require(w > 0 && alb >= 0 && alb < 1 && I >= 0 && t > 0.06 && t < 1,
            "wall>0, 0<=albedo<1, intensity>=0, 0.06<t<1");
    int mat = material("grey", alb, alb, alb, 0);
    const double H = 3.0, Z = 2.0, X = 4.5, XW = 1.5, DW = 0.5, DH = 2.0, DT = 0.05;
    double ht = 0.5 * t;
    box_node("floor", mat, v3(-X - w, -w, -Z - w), v3(X + w, 0, Z + w));
    box_node("ceiling", mat, v3(-X - w, H, -Z - w), v3(X + w, H + w, Z + w));
    box_node("wall_west", mat, v3(-X - w, 0, -Z), v3(-X, H, Z));
    box_node("wall_east", mat, v3(X, 0, -Z), v3(X + w, H, Z));
    box_node("wall_north", mat, v3(-X - w, 0, -Z - w), v3(X + w, H, -Z));
    box_node("wall_south", mat, v3(-X - w, 0, Z), v3(X + w, H, Z + w));
    int dm = material("door", 0.5, 0.5, 0.5, 0);
    int lm = mesh_new("door_leaf", dm);
    add_box(lm, v3(0, 0, 0), v3(DT, DH, 2 * DW));
    static const char *names[2] = { "ab", "bc" };
    for (int k = 0; k < 2; k++) {
        double xc = k ? XW : -XW;
        char nm[32];
        snprintf(nm, sizeof nm, "shared_%s_north", names[k]);
        box_node(nm, mat, v3(xc - ht, 0, -Z), v3(xc + ht, H, -DW));
        snprintf(nm, sizeof nm, "shared_%s_south", names[k]);
        box_node(nm, mat, v3(xc - ht, 0, DW), v3(xc + ht, H, Z));
        snprintf(nm, sizeof nm, "shared_%s_lintel", names[k]);
        box_node(nm, mat, v3(xc - ht, DH, -DW), v3(xc + ht, H, DW));
        snprintf(nm, sizeof nm, "door_%s_closed", names[k]);
        Node *c = mesh_node(nm, lm);
        node_translate(c, v3(xc - 0.5 * DT, 0, -DW));
        node_extra(c, "ubake_door", names[k]);
        if (k == 1 && PI_("combine"))
            node_extra(c, "ubake_combine", "ab");
        snprintf(nm, sizeof nm, "door_%s_open", names[k]);
        Node *op = mesh_node(nm, lm);
        node_translate(op, v3(xc - 0.5 * DT, 0, -DW));
        op->has_r = 1;
        op->r[0] = 0; op->r[1] = sin(M_PI / 4); op->r[2] = 0; op->r[3] = cos(M_PI / 4);
        node_extra(op, "ubake_door_open", names[k]);
    }
    Node *l = light_node("lamp_a", LIGHT_POINT, I, 1, 1, 1, v3(-3.0, 2.0, 0.3));
    node_extra(l, "ubake_light", "static");
}

/* hallway: 12x3x2.5 m corridor along x, four ceiling lamps in two DLS. */
static void build_hallway(void)
{
    double w = P("wall"), alb = P("albedo"), I = P("intensity"), ly = P("lamp_y");
    require(w > 0 && alb >= 0 && alb < 1 && I >= 0 && ly > 0 && ly < 2.5,
            "wall>0, 0<=albedo<1, intensity>=0, 0<lamp_y<2.5");
    int mat = material("wall", alb, alb, alb, 0);
    const double X = 6.0, Z = 1.5, H = 2.5;
    box_node("hall_floor", mat, v3(-X - w, -w, -Z - w), v3(X + w, 0, Z + w));
    box_node("hall_ceiling", mat, v3(-X - w, H, -Z - w), v3(X + w, H + w, Z + w));
    box_node("hall_wall_north", mat, v3(-X - w, 0, -Z - w), v3(X + w, H, -Z));
    box_node("hall_wall_south", mat, v3(-X - w, 0, Z), v3(X + w, H, Z + w));
    box_node("hall_wall_west", mat, v3(-X - w, 0, -Z), v3(-X, H, Z));
    box_node("hall_wall_east", mat, v3(X, 0, -Z), v3(X + w, H, Z));
    static const double lx[4] = { -4.5, -1.5, 1.5, 4.5 };
    for (int i = 0; i < 4; i++) {
        char nm[24];
        snprintf(nm, sizeof nm, "lamp_%d", i + 1);
        Node *l = light_node(nm, LIGHT_POINT, I, 1, 1, 1, v3(lx[i], ly, 0));
        node_extra(l, "ubake_light", i == 1 ? "primary" : "static");
        node_extra(l, "ubake_dls", i < 2 ? "hall_a" : "hall_b");
    }
}

/* inn: a tavern room and a cellar joined by a doorway (Öztürk & Akyüz's inn/dungeon
 * scenes). Hearth (static) and cellar lamp (primary) in the base; candles on the red west
 * wall (DLS "candles"), a torch in the cellar (DLS "torches"). Show/hide objects
 * (ubake_semidynamic): a table, two barrels whose shadows from the hearth overlap on the
 * floor around (2.4, 0, -1.0), and a chest in the cellar. */
static void obj_box(const char *name, int mat, V3 mn, V3 mx)
{
    int m = mesh_new(name, mat);
    add_box(m, mn, mx);
    Node *n = mesh_node(name, m);
    node_extra(n, "ubake_semidynamic", name);
}

static void build_inn(void)
{
    double w = P("wall"), alb = P("albedo"), hearth = P("hearth"), candle = P("candle");
    double torch = P("torch"), lamp = P("lamp");
    const double *red = pv("red");
    require(w > 0 && alb >= 0 && alb < 1 && hearth >= 0 && candle >= 0 && torch >= 0 &&
            lamp >= 0 && red[0] >= 0 && red[0] < 1 && red[1] >= 0 && red[1] < 1 &&
            red[2] >= 0 && red[2] < 1,
            "wall>0, 0<=albedo<1, intensities>=0, 0<=red<1");
    int wm = material("plaster", alb, alb, alb, 0);
    int rm = material("red_plaster", red[0], red[1], red[2], 0);
    int woodm = material("wood", 0.45, 0.3, 0.18, 0);
    const double H = 3.0, Z = 2.5, XA = -3.0, XB = 3.0, XC = 3.2, XD = 7.2, DZ = 0.5, DH = 2.0;
    /* tavern x in [XA, XB], cellar x in [XC, XD], shared wall [XB, XC] with a doorway */
    box_node("floor", wm, v3(XA - w, -w, -Z - w), v3(XD + w, 0, Z + w));
    box_node("ceiling", wm, v3(XA - w, H, -Z - w), v3(XD + w, H + w, Z + w));
    box_node("wall_west", rm, v3(XA - w, 0, -Z - w), v3(XA, H, Z + w));
    box_node("wall_east", wm, v3(XD, 0, -Z - w), v3(XD + w, H, Z + w));
    box_node("wall_north", wm, v3(XA, 0, -Z - w), v3(XD, H, -Z));
    box_node("wall_south", wm, v3(XA, 0, Z), v3(XD, H, Z + w));
    box_node("wall_mid_n", wm, v3(XB, 0, -Z), v3(XC, H, -DZ));
    box_node("wall_mid_s", wm, v3(XB, 0, DZ), v3(XC, H, Z));
    box_node("wall_mid_lintel", wm, v3(XB, DH, -DZ), v3(XC, H, DZ));
    /* objects */
    int tm = mesh_new("table", woodm);
    add_box(tm, v3(-2.0, 0.72, 0.5), v3(-0.8, 0.78, 1.3));
    static const double lx[2] = { -1.95, -0.91 }, lz[2] = { 0.55, 1.19 };
    for (int i = 0; i < 2; i++)
        for (int j = 0; j < 2; j++)
            add_box(tm, v3(lx[i], 0.0, lz[j]), v3(lx[i] + 0.06, 0.72, lz[j] + 0.06));
    Node *tn = mesh_node("table", tm);
    node_extra(tn, "ubake_semidynamic", "table");
    obj_box("barrel_1", woodm, v3(1.2, 0.0, -1.2), v3(1.6, 1.0, -0.8));
    obj_box("barrel_2", woodm, v3(1.8, 0.0, -1.2), v3(2.2, 0.6, -0.8));
    obj_box("chest", woodm, v3(5.0, 0.0, 1.2), v3(5.8, 0.5, 1.7));
    /* lights */
    Node *l = light_node("hearth", LIGHT_POINT, hearth, 1.0, 0.85, 0.7, v3(0.0, 2.5, -1.0));
    node_extra(l, "ubake_light", "static");
    l = light_node("cellar_lamp", LIGHT_POINT, lamp, 1, 1, 1, v3(6.0, 2.7, -1.5));
    node_extra(l, "ubake_light", "primary");
    static const double cz[2] = { 0.9, -0.9 };
    for (int i = 0; i < 2; i++) {
        char nm[24];
        snprintf(nm, sizeof nm, "candle_%d", i + 1);
        l = light_node(nm, LIGHT_POINT, candle, 1, 1, 1, v3(-2.75, 1.6, cz[i]));
        node_extra(l, "ubake_light", "static");
        node_extra(l, "ubake_dls", "candles");
    }
    l = light_node("torch", LIGHT_POINT, torch, 1.0, 0.7, 0.4, v3(7.0, 2.0, 0.0));
    node_extra(l, "ubake_light", "static");
    node_extra(l, "ubake_dls", "torches");
    /* scale variants (bench_objects: 8 sets x 8 objects): barrels along the south wall,
     * sconces on the north wall, each sconce its own set */
    int nb = PI_("extra_barrels"), nsc = PI_("sconces");
    require(nb >= 0 && nb <= 8 && nsc >= 0 && nsc <= 8, "0<=extra_barrels<=8, 0<=sconces<=8");
    for (int i = 0; i < nb; i++) {
        char nm[32];
        snprintf(nm, sizeof nm, "barrel_x%d", i + 1);
        double x = -2.6 + 0.7 * i + (i >= 4 ? 3.4 : 0.0);
        obj_box(nm, woodm, v3(x, 0.0, 1.9), v3(x + 0.4, 0.9, 2.3));
    }
    for (int i = 0; i < nsc; i++) {
        char nm[32];
        snprintf(nm, sizeof nm, "sconce_%d", i + 1);
        l = light_node(nm, LIGHT_POINT, 1.0, 1.0, 0.8, 0.5, v3(-2.5 + 1.3 * i, 2.0, -2.3));
        node_extra(l, "ubake_light", "static");
        node_extra(l, "ubake_dls", nm);
    }
}

/* ---- hard numerical cases (tests/hard/) ---------------------------------- */

/* grazing: black plane, directional light at `angle` degrees from its normal. */
static void build_grazing(void)
{
    double sz = P("size"), E = P("sun"), ang = P("angle"), az = P("azim");
    int n = PI_("n");
    require(sz > 0 && n >= 1 && n <= 256 && E >= 0 && ang >= 0 && ang < 90,
            "size>0, 1<=n<=256, sun>=0, 0<=angle<90");
    int mat = material("black", 0, 0, 0, 0);
    int m = mesh_new("plane", mat);
    add_rect(m, 1, 0.0, v3(-sz / 2, 0, -sz / 2), v3(sz / 2, 0, sz / 2), +1, n);
    mesh_node("plane", m);
    double t = deg2rad(ang), a = deg2rad(az);
    V3 to_sun = v3(sin(t) * sin(a), cos(t), sin(t) * cos(a));
    Node *sn = light_node("sun", LIGHT_DIRECTIONAL, E, 1, 1, 1, vscale(to_sun, 10.0));
    node_aim(sn, vscale(to_sun, -1.0));
    node_extra(sn, "ubake_light", "static");
}

/* tjunction: black size x size floor (y=0, facing +y) under a constant sky,
 * built from indexed triangles with T-junctions, shared and duplicate
 * vertices, zero-area and sliver triangles. */
static void build_tjunction(void)
{
    double sz = P("size"), sl = P("sliver");
    const double *sky = pv("sky");
    require(!PI_("uv1"), "uv1=1 is not supported (the floor is not made of quads)");
    require(sz > 0 && sl > 0 && sl < 0.05 * sz && sky[0] >= 0 && sky[1] >= 0 && sky[2] >= 0,
            "size>0, 0<sliver<size/20, sky>=0");
    int mat = material("black", 0, 0, 0, 0);
    int m = mesh_new("floor", mat);
    V3 up = v3(0, 1, 0);
    double h = 0.5 * sz, q = 0.25 * sz; /* half size, quarter size */
#define FV(x, z) mesh_vertex(m, v3((x), 0, (z)), up)
    /* Left half x in [-h,0]: two squares sharing the edge z=0 through shared
     * vertices, except one corner which is a duplicate (same position, new index). */
    uint32_t a0 = FV(-h, -h), a1 = FV(0, -h), a2 = FV(0, 0), a3 = FV(-h, 0);
    uint32_t a4 = FV(0, h), a5 = FV(-h, h), a3dup = FV(-h, 0);
    mesh_tri(m, a0, a2, a1); mesh_tri(m, a0, a3, a2);           /* z in [-h,0] */
    mesh_tri(m, a3dup, a4, a2); mesh_tri(m, a3dup, a5, a4);     /* z in [0,h] */
    /* Right half x in [0,h]: four strips along z, their corners at z=-q and
     * z=+q are T-junctions on the left squares' edge x=0. */
    uint32_t r[5][2];
    for (int k = 0; k < 5; k++) { r[k][0] = FV(0, -h + k * q); r[k][1] = FV(h, -h + k * q); }
    mesh_tri(m, r[0][0], r[1][1], r[0][1]); mesh_tri(m, r[0][0], r[1][0], r[1][1]); /* [-h,-q] */
    mesh_tri(m, r[1][0], r[2][1], r[1][1]); mesh_tri(m, r[1][0], r[2][0], r[2][1]); /* [-q,0] */
    /* [0,q] split at x=h/2: T-junction at (h/2, 0) on the edge of [-q,0] */
    uint32_t b0 = FV(0.5 * h, 0), b1 = FV(0.5 * h, q);
    mesh_tri(m, r[2][0], r[3][0], b1); mesh_tri(m, r[2][0], b1, b0);
    mesh_tri(m, b0, b1, r[3][1]); mesh_tri(m, b0, r[3][1], r[2][1]);
    /* [q,h] as a fan around E, `sliver` above the edge z=q: (A,B,E) is a sliver
     * (altitude `sliver` over a size/2 edge), the others are ordinary. */
    uint32_t A = r[3][0], B = r[3][1], C = r[4][1], D = r[4][0];
    uint32_t E = FV(0.5 * h, q + sl);
    mesh_tri(m, A, E, B); mesh_tri(m, B, E, C); mesh_tri(m, C, E, D); mesh_tri(m, D, E, A);
    /* Zero-area triangles in the middle of the floor: collinear along the
     * T-junction seam x=0, two corners at one position (duplicate vertex), and
     * a repeated index. */
    uint32_t c0 = FV(0, -h), c1 = FV(0, -q), c2 = FV(0, 0);
    mesh_tri(m, c0, c1, c2);
    uint32_t d0 = FV(0.5 * h, 0), d1 = FV(0.5 * h, 0), d2 = FV(h, 0);
    mesh_tri(m, d0, d1, d2);
    mesh_tri(m, a2, a2, a4);
    /* A sliver below the loader's degenerate threshold (altitude 1e-7 m). */
    uint32_t s0 = FV(-h, 0.5 * q), s1 = FV(0, 0.5 * q), s2 = FV(-0.5 * h, 0.5 * q + 1e-7);
    mesh_tri(m, s0, s2, s1);
#undef FV
    mesh_node("floor", m);
    S.has_sky = 1;
    memcpy(S.sky, sky, sizeof S.sky);
}

/* room: closed 4x3x4 m room (inward single-sided quads) with a point light,
 * translated by `offset`; `marker`=1 adds a 1 m closed box at the origin so
 * the level spans from the origin to the room. */
static void build_room(void)
{
    const double *off = pv("offset");
    double alb = P("albedo"), I = P("intensity");
    const double *lp = pv("light_pos");
    int n = PI_("n"), marker = PI_("marker");
    V3 o = v3(off[0], off[1], off[2]);
    require(alb >= 0 && alb < 1 && I >= 0 && n >= 1 && n <= 64 && lp[0] > 0 && lp[0] < 4 && lp[1] > 0 &&
            lp[1] < 3 && lp[2] > 0 && lp[2] < 4,
            "0<=albedo<1, intensity>=0, 1<=n<=64, light_pos inside (0,4)x(0,3)x(0,4)");
    require(!marker || fabs(o.x) > 2 || fabs(o.z) > 2 || o.y > 1 || o.y < -3,
            "marker=1 needs the room offset clear of the marker box at the origin");
    int mat = material("room", alb, alb, alb, 0);
    static const char *names[6] = { "room_wall_xneg", "room_wall_xpos", "room_floor",
                                    "room_ceiling", "room_wall_zneg", "room_wall_zpos" };
    V3 lo = o, hi = vadd(o, v3(4, 3, 4));
    for (int a = 0; a < 3; a++)
        for (int sd = 0; sd < 2; sd++) {
            int m = mesh_new(names[2 * a + sd], mat);
            add_rect(m, a, sd ? vget(hi, a) : vget(lo, a), lo, hi, sd ? -1 : +1, n); /* inward */
            mesh_node(names[2 * a + sd], m);
        }
    Node *l = light_node("light", LIGHT_POINT, I, 1, 1, 1, vadd(o, v3(lp[0], lp[1], lp[2])));
    node_extra(l, "ubake_light", "static");
    if (marker) box_node("marker", mat, v3(-0.5, 0, -0.5), v3(0.5, 1, 0.5));
    if (PI_("props")) {
        /* LLG-by-default check: a 15 cm stool (poor charts: becomes an LLG), a 0.8 m crate
         * (good charts: stays lightmapped), the same stool tagged lightmap (the tag wins). */
        box_node("prop_stool", mat, vadd(o, v3(0.9, 0, 0.9)), vadd(o, v3(1.05, 0.15, 1.05)));
        box_node("prop_crate", mat, vadd(o, v3(2.6, 0, 0.6)), vadd(o, v3(3.4, 0.8, 1.4)));
        box_node("prop_tagged", mat, vadd(o, v3(0.9, 0, 2.9)), vadd(o, v3(1.05, 0.15, 3.05)));
        node_extra(&S.nodes[S.nnode - 1], "ubake_receiver", "lightmap");
    }
}

/* sunpatch: closed room (slabs) with a small window in the ceiling; a very
 * bright sun makes a small patch on the floor, a dim point light lights the
 * rest. */
static void build_sunpatch(void)
{
    double w = P("wall"), alb = P("albedo"), E = P("sun"), I = P("intensity"), win = P("window");
    double el = P("elev"), az = P("azim");
    const double *wc = pv("window_at"), *lp = pv("light_pos");
    const double R = 2.0, H = 3.0;
    require(w > 0 && alb >= 0 && alb < 1 && E >= 0 && I >= 0 && win > 0 && el > 0 && el <= 90 &&
            fabs(wc[0]) + 0.5 * win < R && fabs(wc[2]) + 0.5 * win < R && fabs(lp[0]) < R &&
            fabs(lp[2]) < R && lp[1] > 0 && lp[1] < H,
            "wall>0, 0<=albedo<1, sun>=0, intensity>=0, window>0 inside the ceiling, 0<elev<=90, light inside");
    int mat = material("wall", alb, alb, alb, 0);
    double o = R + w;
    box_node("floor", mat, v3(-o, -w, -o), v3(o, 0, o));
    box_node("wall_north", mat, v3(-o, 0, -o), v3(o, H, -R));
    box_node("wall_south", mat, v3(-o, 0, R), v3(o, H, o));
    box_node("wall_west", mat, v3(-o, 0, -R), v3(-R, H, R));
    box_node("wall_east", mat, v3(R, 0, -R), v3(o, H, R));
    /* Ceiling slab y in [H,H+w] around the window [x0,x1]x[z0,z1]: 4 boxes. */
    double x0 = wc[0] - 0.5 * win, x1 = wc[0] + 0.5 * win, z0 = wc[2] - 0.5 * win, z1 = wc[2] + 0.5 * win;
    box_node("ceiling_west", mat, v3(-o, H, -o), v3(x0, H + w, o));
    box_node("ceiling_east", mat, v3(x1, H, -o), v3(o, H + w, o));
    box_node("ceiling_north", mat, v3(x0, H, -o), v3(x1, H + w, z0));
    box_node("ceiling_south", mat, v3(x0, H, z1), v3(x1, H + w, o));
    double e = deg2rad(el), a = deg2rad(az);
    V3 to_sun = v3(sin(a) * cos(e), sin(e), cos(a) * cos(e));
    Node *sn = light_node("sun", LIGHT_DIRECTIONAL, E, 1, 1, 1, vadd(v3(wc[0], H + 10, wc[2]), vscale(to_sun, 10.0)));
    node_aim(sn, vscale(to_sun, -1.0));
    node_extra(sn, "ubake_light", "static");
    Node *l = light_node("lamp", LIGHT_POINT, I, 1, 1, 1, v3(lp[0], lp[1], lp[2]));
    node_extra(l, "ubake_light", "static");
}

/* mis_edge: black floor and emitters placed where one sampling strategy has
 * zero pdf: coplanar with the floor (edge-on), touching it, facing away from
 * it, and under it (facing its back). */
static void build_mis_edge(void)
{
    double le = P("le"), alb = P("albedo");
    require(le >= 0 && alb >= 0 && alb < 1, "le>=0, 0<=albedo<1");
    int fm = material("floor", alb, alb, alb, 0);
    int em = material("emitter", 0, 0, 0, le);
    int m = mesh_new("floor", fm);
    add_rect(m, 1, 0.0, v3(-2, 0, -2), v3(2, 0, 2), +1, 1);
    mesh_node("floor", m);
    m = mesh_new("em_coplanar", em);         /* y=0 facing +y, shares the floor edge x=2 */
    add_rect(m, 1, 0.0, v3(2, 0, -1), v3(3, 0, 1), +1, 1);
    mesh_node("em_coplanar", m);
    m = mesh_new("em_touching", em);         /* x=-1 facing +x, bottom edge on the floor */
    add_rect(m, 0, -1.0, v3(0, 0, -0.5), v3(0, 1, 0.5), +1, 1);
    mesh_node("em_touching", m);
    m = mesh_new("em_away", em);             /* y=1 facing +y: its back to the floor */
    add_rect(m, 1, 1.0, v3(0.5, 0, -1.5), v3(1.5, 0, -0.5), +1, 1);
    mesh_node("em_away", m);
    m = mesh_new("em_below", em);            /* y=-0.5 facing +y: toward the floor's back */
    add_rect(m, 1, -0.5, v3(-1, 0, 0.5), v3(1, 0, 1.5), +1, 1);
    mesh_node("em_below", m);
    m = mesh_new("em_edgeon", em);           /* triangle in the plane z=1.8, seen edge-on along z=1.8 */
    add_tri(m, v3(0.5, 0.0, 1.8), v3(1.5, 0.0, 1.8), v3(1.0, 0.8, 1.8), v3(0, 0, -1));
    mesh_node("em_edgeon", m);
}

/* ---- scale level (UberBake Table 1, ESTATE) ----------------------------- */

/* Deterministic uniform number in [0,1) from (seed, a, b, c): splitmix64 finaliser. */
static double est_hash(uint64_t seed, uint64_t a, uint64_t b, uint64_t c)
{
    uint64_t z = seed * 0x9E3779B97F4A7C15ull ^ a * 0xBF58476D1CE4E5B9ull ^ b * 0x94D049BB133111EBull ^
                 c * 0xD6E8FEB86659FD93ull;
    z ^= z >> 30; z *= 0xBF58476D1CE4E5B9ull;
    z ^= z >> 27; z *= 0x94D049BB133111EBull;
    z ^= z >> 31;
    return (double)(z >> 11) * (1.0 / 9007199254740992.0);
}

/* A common parameter (texel_size, glg_spacing) the user did not set takes this level's
 * default (the writer reads it from g_val). */
static void common_default(const char *key, double v)
{
    int i = param_index(g_level, key);
    if (i < 0) die("internal: no common parameter %s", key);
    if (!g_set[i]) g_val[i][0] = v;
}

/* Wall segment along `axis` (0: runs along x at z = c, 1: runs along z at x = c) from a to
 * b, thickness w, height H, into mesh mi; door=1 cuts a dw x dh doorway in its middle
 * (two jamb pieces and a lintel, closed boxes that touch). */
static void est_wall(int mi, int axis, double c, double a, double b, double w, double H, int door,
                     double dw, double dh)
{
    double h = 0.5 * w;
#define EST_BOX(u0, u1, y0, y1)                                                               \
    do {                                                                                      \
        if (axis == 0) add_box(mi, v3((u0), (y0), c - h), v3((u1), (y1), c + h));             \
        else add_box(mi, v3(c - h, (y0), (u0)), v3(c + h, (y1), (u1)));                       \
    } while (0)
    if (!door) {
        EST_BOX(a, b, 0.0, H);
    } else {
        double m = 0.5 * (a + b);
        EST_BOX(a, m - 0.5 * dw, 0.0, H);
        EST_BOX(m + 0.5 * dw, b, 0.0, H);
        EST_BOX(m - 0.5 * dw, m + 0.5 * dw, dh, H);
    }
#undef EST_BOX
}

/* estate: a one-storey manor of `rooms` square rooms on a grid around a great hall of
 * hall x hall cells, doorways between some neighbours. `overlap` dynamic light sets share
 * the hall (every hall texel sees all of them directly); the other sets are scattered
 * over the rooms (0-4 per room); rooms without a set have one static lamp. Props
 * (closed boxes tagged ubake_receiver: llg) stand in a 4x4 grid of slots per cell.
 * `scale` shrinks rooms, room sets and props together; the hall stays. */
static void build_estate(void)
{
    double scale = P("scale"), L = P("room"), H = P("height"), w = P("wall"), alb = P("albedo");
    double I = P("intensity"), pdoor = P("doors");
    int rooms_full = PI_("rooms"), sets_full = PI_("sets"), hall_sets = PI_("overlap");
    int lps = PI_("lights_per_set"), hall = PI_("hall");
    double props = P("props");
    uint64_t seed = (uint64_t)PI_("seed");
    require(scale > 0 && scale <= 1 && L >= 4 && L <= 64 && H >= 2.5 && H <= 20 && w > 0 && w <= 0.5 &&
                alb >= 0 && alb < 1 && I >= 0 && pdoor >= 0 && pdoor <= 1 && rooms_full >= 0 &&
                sets_full >= 0 && hall_sets >= 0 && hall_sets <= sets_full && lps >= 1 && lps <= 16 &&
                hall >= 1 && hall <= 8 && props >= 0 && props <= 16 && P("seed") >= 0,
            "0<scale<=1, 4<=room<=64, 2.5<=height<=20, 0<wall<=0.5, 0<=albedo<1, intensity>=0, "
            "0<=doors<=1, rooms>=0, 0<=overlap<=sets, 1<=lights_per_set<=16, 1<=hall<=8, 0<=props<=16, seed>=0");
    common_default("texel_size", 0.138);
    common_default("glg_spacing", 0.85);
    int nrooms = (int)lround(rooms_full * scale);
    int room_sets = (int)lround((sets_full - hall_sets) * scale);
    if (room_sets > 0 && nrooms < 1) nrooms = 1;
    require(room_sets <= 4 * nrooms, "at most 4 sets per room (raise rooms or lower sets)");
    /* Grid: the hall block in the middle, rooms fill the rest row by row. */
    int cells = nrooms + hall * hall;
    int cols = (int)ceil(sqrt((double)cells));
    if (cols < hall) cols = hall;
    int rows = (cells + cols - 1) / cols;
    if (rows < hall) rows = hall;
    int hx0 = (cols - hall) / 2, hz0 = (rows - hall) / 2;
#define IN_HALL(i, j) ((i) >= hx0 && (i) < hx0 + hall && (j) >= hz0 && (j) < hz0 + hall)
    /* Which cells are rooms: the first nrooms non-hall cells in row order (the last row
     * may be partly empty: no floor, walls close the rooms around it). */
    int *room_of = xrealloc(NULL, (size_t)cols * rows * sizeof *room_of);
    int nr = 0;
    for (int j = 0; j < rows; j++)
        for (int i = 0; i < cols; i++) {
            int c = j * cols + i;
            room_of[c] = IN_HALL(i, j) ? -2 : (nr < nrooms ? nr++ : -1);
        }
    /* -2 hall, -1 empty (outside), >= 0 room index */
#define CELL(i, j) ((i) < 0 || (j) < 0 || (i) >= cols || (j) >= rows ? -1 : room_of[(j) * cols + (i)])
    int mat = material("plaster", alb, alb, alb, 0);
    int pmat = material("furniture", 0.5 * alb + 0.1, 0.45 * alb + 0.05, 0.35 * alb, 0);
    const double hw = 0.5 * w, DW = 1.2, DH = 2.4;
    /* One mesh per occupied cell (floor, ceiling, the walls it owns); the hall's floor
     * and ceiling are one quad each, in the mesh of its first cell. */
    int *cmesh = xrealloc(NULL, (size_t)cols * rows * sizeof *cmesh);
    for (int j = 0; j < rows; j++)
        for (int i = 0; i < cols; i++) {
            int k = CELL(i, j);
            cmesh[j * cols + i] = -1;
            if (k == -1) continue;
            char nm[64];
            if (k == -2) snprintf(nm, sizeof nm, "hall_%d_%d", i, j);
            else snprintf(nm, sizeof nm, "room_%d_%d", i, j);
            int m = mesh_new(nm, mat);
            cmesh[j * cols + i] = m;
            if (k >= 0 || (i == hx0 && j == hz0)) {
                double x0 = i * L + hw, z0 = j * L + hw;
                double x1 = (k >= 0 ? i + 1 : hx0 + hall) * L - hw, z1 = (k >= 0 ? j + 1 : hz0 + hall) * L - hw;
                add_rect(m, 1, 0.0, v3(x0, 0, z0), v3(x1, 0, z1), +1, 1);
                add_rect(m, 1, H, v3(x0, 0, z0), v3(x1, 0, z1), -1, 1);
            }
        }
    /* Walls on grid lines between an occupied cell and anything different (a wall
     * between two hall cells is left out); pillars at grid points next to any occupied
     * cell (in the hall: columns). Each goes to the mesh of an occupied neighbour. */
    int doors = 0, wall_segs = 0;
    for (int orient = 0; orient < 2; orient++) /* 0: lines z = j*L, 1: lines x = i*L */
        for (int a = 0; a <= (orient ? cols : rows); a++)
            for (int b = 0; b < (orient ? rows : cols); b++) {
                int ci = orient ? a : b, cj = orient ? b : a;     /* cell on the + side */
                int pi = orient ? a - 1 : b, pj = orient ? b : a - 1; /* cell on the - side */
                int kp = CELL(ci, cj), km = CELL(pi, pj);
                if (kp == -1 && km == -1) continue;
                if (kp == -2 && km == -2) continue;
                int owner = kp != -1 ? cj * cols + ci : pj * cols + pi;
                int door = kp != -1 && km != -1 && est_hash(seed, 1, (uint64_t)(orient * 4096 + a), (uint64_t)b) < pdoor;
                est_wall(cmesh[owner], orient ? 1 : 0, a * L, b * L + hw, (b + 1) * L - hw, w, H, door, DW, DH);
                doors += door;
                wall_segs++;
            }
    for (int j = 0; j <= rows; j++)
        for (int i = 0; i <= cols; i++) {
            int owner = -1;
            for (int q = 0; q < 4 && owner < 0; q++) {
                int ci = i - (q & 1), cj = j - (q >> 1);
                if (CELL(ci, cj) != -1) owner = cj * cols + ci;
            }
            if (owner < 0) continue;
            add_box(cmesh[owner], v3(i * L - hw, 0, j * L - hw), v3(i * L + hw, H, j * L + hw));
        }
    for (int c = 0; c < cols * rows; c++)
        if (cmesh[c] >= 0) mesh_node(S.meshes[cmesh[c]].name, cmesh[c]);
    /* Props: up to 16 slots per cell (4x4), a box of 0.6-1.2 m footprint, 0.5-1.2 m tall. */
    int nprops = 0;
    const double slot = (L - w) / 4.0;
    for (int j = 0; j < rows; j++)
        for (int i = 0; i < cols; i++) {
            if (CELL(i, j) == -1) continue;
            /* props per cell: floor(props), one more with probability frac(props) */
            int np = (int)props + (est_hash(seed, 9, (uint64_t)(j * cols + i), 0) < props - floor(props));
            for (int s = 0; s < np; s++) {
                /* slot s of a fixed permutation of the 16, so props spread over the cell */
                static const int perm[16] = { 5, 10, 0, 15, 3, 12, 6, 9, 1, 14, 7, 8, 2, 13, 4, 11 };
                int sx = perm[s] % 4, sz = perm[s] / 4;
                double cx = i * L + hw + (sx + 0.5) * slot, cz = j * L + hw + (sz + 0.5) * slot;
                double fx = 0.6 + 0.6 * est_hash(seed, 2, (uint64_t)(j * cols + i), (uint64_t)s);
                double fz = 0.6 + 0.6 * est_hash(seed, 3, (uint64_t)(j * cols + i), (uint64_t)s);
                double fy = 0.5 + 0.7 * est_hash(seed, 4, (uint64_t)(j * cols + i), (uint64_t)s);
                if (fx > slot - 0.4) fx = slot - 0.4;
                if (fz > slot - 0.4) fz = slot - 0.4;
                char nm[64];
                snprintf(nm, sizeof nm, "prop_%d_%d_%d", i, j, s);
                int m = mesh_new(nm, pmat);
                add_box(m, v3(cx - 0.5 * fx, 0, cz - 0.5 * fz), v3(cx + 0.5 * fx, fy, cz + 0.5 * fz));
                Node *n = mesh_node(nm, m);
                node_extra(n, "ubake_receiver", "llg");
                nprops++;
            }
        }
    /* Sets per room: room sets scattered by hash, at most 4 per room. */
    int *nset = xrealloc(NULL, (size_t)(nrooms > 0 ? nrooms : 1) * sizeof *nset);
    memset(nset, 0, (size_t)(nrooms > 0 ? nrooms : 1) * sizeof *nset);
    for (int s = 0; s < room_sets; s++) {
        int r = (int)(est_hash(seed, 5, (uint64_t)s, 0) * nrooms);
        while (nset[r] >= 4) r = (r + 1) % nrooms;
        nset[r]++;
    }
    int nlights = 0, nsets = 0, max_room_sets = 0;
    const double ly = H - 0.6, margin = 1.0;
    for (int j = 0; j < rows; j++)
        for (int i = 0; i < cols; i++) {
            int k = CELL(i, j);
            if (k == -1 || (k == -2 && !(i == hx0 && j == hz0))) continue;
            int span = k == -2 ? hall : 1;
            double x0 = i * L + hw + margin, z0 = j * L + hw + margin;
            double ext = span * L - w - 2 * margin;
            int ns = k == -2 ? hall_sets : nset[k];
            if (ns > max_room_sets && k >= 0) max_room_sets = ns;
            if (ns == 0) {
                char nm[64];
                snprintf(nm, sizeof nm, "lamp_%d_%d", i, j);
                Node *l = light_node(nm, LIGHT_POINT, I, 1.0, 0.95, 0.85,
                                     v3(x0 + 0.5 * ext, ly, z0 + 0.5 * ext));
                node_extra(l, "ubake_light", "static");
                nlights++;
                continue;
            }
            for (int s = 0; s < ns; s++, nsets++) {
                char set[48];
                if (k == -2) snprintf(set, sizeof set, "hall_%02d", s);
                else snprintf(set, sizeof set, "room_%d_%d_%d", i, j, s);
                /* warm or cool sets, alternately static and primary */
                double warm = est_hash(seed, 6, (uint64_t)nsets, 0);
                for (int l = 0; l < lps; l++) {
                    char nm[72];
                    snprintf(nm, sizeof nm, "lamp_%s_%d", set, l);
                    double lx = x0 + est_hash(seed, 7, (uint64_t)nsets, (uint64_t)l) * ext;
                    double lz = z0 + est_hash(seed, 8, (uint64_t)nsets, (uint64_t)l) * ext;
                    /* keep clear of the hall's columns (at the grid points) */
                    double gx = lx - L * floor(lx / L + 0.5), gz = lz - L * floor(lz / L + 0.5);
                    if (fabs(gx) < 0.5 && fabs(gz) < 0.5) lx += gx < 0 ? -0.5 : 0.5;
                    Node *ln = light_node(nm, LIGHT_POINT, I / lps, 0.8 + 0.2 * warm, 0.9, 1.0 - 0.2 * warm,
                                          v3(lx, ly, lz));
                    node_extra(ln, "ubake_light", nsets % 2 ? "primary" : "static");
                    node_extra(ln, "ubake_dls", set);
                    nlights++;
                }
            }
        }
    /* What was made, and the rough receiver budget: interior surface area / texel size^2
     * (the baker adds chart padding), props' LLG grids (UB_LLG_SPACING 0.3 m, padded). */
    printf("estate: %d x %d cells of %g m, %d rooms + hall %dx%d cells, %d wall segments (%d doorways), "
           "%d sets (%d in the hall), %d lights, %d props (llg)\n",
           cols, rows, L, nrooms, hall, hall, wall_segs, doors, nsets, hall_sets, nlights, nprops);
    free(room_of);
    free(cmesh);
    free(nset);
    (void)max_room_sets;
#undef IN_HALL
#undef CELL
}

static const LevelDef g_levels[] = {
    { "cornell", "Cornell box (2 m), closed by default; point light or emissive ceiling patch.", build_cornell,
      { { "open", 1, { 0 }, "1: omit the front wall (z=+1)" },
        { "emissive", 1, { 0 }, "1: emissive 0.5x0.5 m ceiling patch instead of the point light" },
        { "light", 1, { 4 }, "point light intensity, W/sr (white)" },
        { "light_y", 1, { 1.9 }, "point light height, m (x=z=0)" },
        { "le", 1, { 10 }, "emissive patch radiance, W/(m^2 sr)" },
        { "patch", 1, { 0.5 }, "emissive patch side, m" },
        { "lamps", 1, { 0 }, "small dim emissive wall lamps (0.12 m square, 25 cm up), 0-4" },
        { "lamp_le", 1, { 2 }, "their radiance, W/(m^2 sr)" } } },
    { "furnace", "Closed cube furnace: uniform albedo and emission; E = pi*Le*sum_k rho^k.", build_furnace,
      { { "rho", 1, { 0.5 }, "albedo of every face (1 allowed: ubake clamps albedo to 0.999)" },
        { "le", 1, { 1.0 }, "emitted radiance of every face, W/(m^2 sr)" },
        { "n", 1, { 4 }, "each face split into n x n quads" },
        { "size", 1, { 2 }, "cube side, m (x,z in [-size/2,size/2], y in [0,size])" } } },
    { "plane_point", "Black plane + point light: E = I*h/(h^2+r^2)^1.5.", build_plane_point,
      { { "h", 1, { 1 }, "light height above the origin, m" },
        { "intensity", 1, { 10 }, "point light intensity, W/sr" },
        { "size", 1, { 20 }, "plane side, m" },
        { "n", 1, { 10 }, "plane split into n x n quads" } } },
    { "sky_plane", "Black plane under a constant sky: E = pi*L_sky.", build_sky_plane,
      { { "sky", 3, { 0.5, 0.7, 1.0 }, "sky radiance r,g,b, W/(m^2 sr)" },
        { "size", 1, { 20 }, "plane side, m" },
        { "n", 1, { 10 }, "plane split into n x n quads" } } },
    { "two_rooms", "Two closed rooms sharing one thin wall; light in A only, B must stay dark (leak test).",
      build_two_rooms,
      { { "t", 1, { 0.05 }, "shared wall thickness, m (centred on x=0)" },
        { "wall", 1, { 0.2 }, "outer wall/floor/ceiling slab thickness, m" },
        { "albedo", 1, { 0.7 }, "albedo of every surface" },
        { "intensity", 1, { 20 }, "room A point light intensity, W/sr" },
        { "light_y", 1, { 2 }, "room A point light height, m" } } },
    { "sunroom", "Dark room, doorway, ground, sun + sky; door leaf with closed/open poses.", build_sunroom,
      { { "door", 1, { 1 }, "0: no door leaves (doorway open)" },
        { "sun", 1, { 5 }, "sun irradiance at normal incidence, W/m^2" },
        { "elev", 1, { 45 }, "sun elevation, degrees" },
        { "azim", 1, { 0 }, "sun azimuth, degrees (0: sun in the +z direction, 90: +x)" },
        { "sky", 3, { 0.3, 0.4, 0.6 }, "sky radiance r,g,b" },
        { "albedo", 1, { 0.6 }, "room albedo" },
        { "ground_albedo", 1, { 0.3 }, "ground albedo" },
        { "ground", 1, { 40 }, "ground side, m" },
        { "wall", 1, { 0.2 }, "wall/floor/ceiling thickness, m" } } },
    { "door_small", "Sunroom with a 10 cm hatch 1.5 m up as the door: tiny portal far from the receivers.", build_door_small,
      { { "door", 1, { 1 }, "0: no door leaves (doorway open)" },
        { "sun", 1, { 5 }, "sun irradiance at normal incidence, W/m^2" },
        { "elev", 1, { 20 }, "sun elevation, degrees" },
        { "azim", 1, { 0 }, "sun azimuth, degrees (0: sun in the +z direction, 90: +x)" },
        { "sky", 3, { 0.3, 0.4, 0.6 }, "sky radiance r,g,b" },
        { "albedo", 1, { 0.6 }, "room albedo" },
        { "ground_albedo", 1, { 0.3 }, "ground albedo" },
        { "ground", 1, { 40 }, "ground side, m" },
        { "wall", 1, { 0.2 }, "wall/floor/ceiling thickness, m" } } },
    { "door_grazing", "Sunroom whose open leaf lies 10 degrees off the inner wall; low sun from the side.", build_door_grazing,
      { { "door", 1, { 1 }, "0: no door leaves (doorway open)" },
        { "sun", 1, { 5 }, "sun irradiance at normal incidence, W/m^2" },
        { "elev", 1, { 25 }, "sun elevation, degrees" },
        { "azim", 1, { 35 }, "sun azimuth, degrees (0: sun in the +z direction, 90: +x)" },
        { "sky", 3, { 0.3, 0.4, 0.6 }, "sky radiance r,g,b" },
        { "albedo", 1, { 0.6 }, "room albedo" },
        { "ground_albedo", 1, { 0.3 }, "ground albedo" },
        { "ground", 1, { 40 }, "ground side, m" },
        { "wall", 1, { 0.2 }, "wall/floor/ceiling thickness, m" } } },
    { "door_rooms", "Two rooms joined by a door; lamp in room A, room B lit only through the door.",
      build_door_rooms,
      { { "t", 1, { 0.2 }, "shared wall thickness, m" },
        { "wall", 1, { 0.2 }, "outer slab thickness, m" },
        { "albedo", 1, { 0.6 }, "albedo of every surface" },
        { "intensity", 1, { 20 }, "lamp intensity, W/sr" } } },
    { "door_combo", "door_rooms with a light leaf, lamp A, DLS lamp_b in room B; door tagged ubake_combine lamp_b.",
      build_door_combo,
      { { "t", 1, { 0.2 }, "shared wall thickness, m" },
        { "wall", 1, { 0.2 }, "outer slab thickness, m" },
        { "albedo", 1, { 0.6 }, "albedo of every surface but the leaf" },
        { "intensity", 1, { 20 }, "lamp A intensity, W/sr (static, base)" },
        { "leaf_albedo", 1, { 0.8 }, "door leaf albedo" },
        { "lamp_a_at", 3, { -2.0, 2.0, 0.5 }, "lamp A position, m (room A: x<0)" },
        { "lamp_b", 1, { 10 }, "lamp B intensity, W/sr (DLS lamp_b; 0: no lamp B)" },
        { "lamp_b_at", 3, { 2.0, 2.0, -0.5 }, "lamp B position, m (room B: x>0)" },
        { "combine", 1, { 1 }, "1: the door node carries ubake_combine: lamp_b" },
        { "black_leaf", 1, { 0 }, "1: closed leaf tagged ubake_receiver none (black in the base: no S_C)" } } },
    { "door_chain", "Rooms A | B | C joined by doors ab and bc in line, lamp in A; bc tagged ubake_combine ab (door x door).",
      build_door_chain,
      { { "t", 1, { 0.2 }, "shared wall thickness, m" },
        { "wall", 1, { 0.2 }, "outer slab thickness, m" },
        { "albedo", 1, { 0.6 }, "albedo of every surface but the leaves (0.5)" },
        { "intensity", 1, { 20 }, "lamp intensity, W/sr" },
        { "combine", 1, { 1 }, "1: door bc carries ubake_combine: ab" } } },
    { "hallway", "12x3x2.5 m corridor, 4 ceiling lamps in DLS hall_a (1,2) / hall_b (3,4); lamp 2 primary.",
      build_hallway,
      { { "intensity", 1, { 5 }, "each lamp, W/sr" },
        { "albedo", 1, { 0.6 }, "albedo of every surface" },
        { "lamp_y", 1, { 2.4 }, "lamp height, m" },
        { "wall", 1, { 0.2 }, "wall/floor/ceiling thickness, m" } } },
    { "inn", "Tavern + cellar joined by a doorway: hearth, cellar lamp (primary), candles and torch in DLS; show/hide table, barrel_1, barrel_2 (overlapping shadows), chest.",
      build_inn,
      { { "hearth", 1, { 6 }, "hearth intensity, W/sr (warm)" },
        { "lamp", 1, { 3 }, "cellar lamp intensity, W/sr (primary)" },
        { "candle", 1, { 1.5 }, "each candle, W/sr (DLS candles)" },
        { "torch", 1, { 4 }, "torch intensity, W/sr (DLS torches)" },
        { "albedo", 1, { 0.6 }, "plaster albedo" },
        { "red", 3, { 0.75, 0.12, 0.08 }, "west wall albedo" },
        { "extra_barrels", 1, { 0 }, "extra show/hide barrels along the south walls (0-8)" },
        { "sconces", 1, { 0 }, "extra wall sconces on the north wall, each its own DLS (0-8)" },
        { "wall", 1, { 0.2 }, "wall/floor/ceiling thickness, m" } } },
    { "grazing", "Black plane, directional light at a grazing angle: E = sun*cos(angle).", build_grazing,
      { { "angle", 1, { 89.9 }, "angle between the light and the plane normal, degrees" },
        { "azim", 1, { 30 }, "azimuth of the light about +y, degrees (0: from +z)" },
        { "sun", 1, { 1000 }, "irradiance at normal incidence, W/m^2" },
        { "size", 1, { 4 }, "plane side, m" },
        { "n", 1, { 4 }, "plane split into n x n quads" } } },
    { "tjunction", "Black floor under a constant sky, made of T-junctions, duplicate vertices, zero-area and sliver triangles: E = pi*L_sky.",
      build_tjunction,
      { { "sky", 3, { 1, 1, 1 }, "sky radiance r,g,b, W/(m^2 sr)" },
        { "size", 1, { 4 }, "floor side, m" },
        { "sliver", 1, { 1e-4 }, "altitude of the sliver triangle, m" } } },
    { "room", "Closed 4x3x4 m room with a point light, translated by offset (float precision); marker=1 adds a box at the origin.",
      build_room,
      { { "offset", 3, { 0, 0, 0 }, "room corner (interior is offset + [0,4]x[0,3]x[0,4]), m" },
        { "marker", 1, { 0 }, "1: add a 1 m closed box at the origin (the level spans origin..room)" },
        { "albedo", 1, { 0.5 }, "albedo of every face" },
        { "intensity", 1, { 10 }, "point light intensity, W/sr" },
        { "light_pos", 3, { 2, 2, 2 }, "light position relative to the room corner, m" },
        { "n", 1, { 1 }, "each face split into n x n quads" },
        { "props", 1, { 0 }, "1: add untagged boxes prop_stool (0.15 m) and prop_crate (0.8 m), and prop_tagged (0.15 m, ubake_receiver lightmap)" } } },
    { "sunpatch", "Closed 4x3x4 m room, dim lamp, very bright sun through a small ceiling window (fireflies).",
      build_sunpatch,
      { { "sun", 1, { 1e5 }, "sun irradiance at normal incidence, W/m^2" },
        { "intensity", 1, { 1 }, "lamp intensity, W/sr" },
        { "light_pos", 3, { -1, 2.5, 1 }, "lamp position, m" },
        { "window", 1, { 0.2 }, "ceiling window side, m" },
        { "window_at", 3, { 1.2, 3, 1.2 }, "window centre (x, -, z), m" },
        { "elev", 1, { 90 }, "sun elevation, degrees" },
        { "azim", 1, { 0 }, "sun azimuth, degrees" },
        { "albedo", 1, { 0.5 }, "albedo of every surface" },
        { "wall", 1, { 0.2 }, "wall/floor/ceiling thickness, m" } } },
    { "mis_edge", "Black floor, emitters edge-on (coplanar), touching, facing away and below it (zero-pdf MIS).",
      build_mis_edge,
      { { "le", 1, { 1 }, "emitter radiance, W/(m^2 sr)" },
        { "albedo", 1, { 0 }, "floor albedo" } } },
    { "estate", "ESTATE-scale manor (UberBake Table 1): rooms around a great hall, 132 dynamic light sets, up to 16 per texel, LLG props; big: not in --all.",
      build_estate,
      { { "scale", 1, { 1 }, "fraction of the full estate: rooms, room sets and props scale with it; the hall stays" },
        { "rooms", 1, { 100 }, "rooms at scale 1 (one grid cell each, besides the hall)" },
        { "sets", 1, { 132 }, "dynamic light sets at scale 1, the hall's included" },
        { "overlap", 1, { 16 }, "sets sharing the great hall: what a hall texel sees (the level's max overlap, plus leaks through doorways)" },
        { "lights_per_set", 1, { 2 }, "point lamps per set (each intensity/lights_per_set)" },
        { "hall", 1, { 3 }, "great hall side, in cells" },
        { "props", 1, { 3.5 }, "LLG props (closed boxes, ubake_receiver llg) per cell, 0-16 (a fraction: some cells get one more)" },
        { "room", 1, { 8 }, "cell side, m (walls centred on the grid lines)" },
        { "height", 1, { 4 }, "storey height, m" },
        { "doors", 1, { 0.5 }, "fraction of interior walls with a 1.2x2.4 m doorway" },
        { "intensity", 1, { 20 }, "each room lamp / each set (split over its lamps), W/sr" },
        { "albedo", 1, { 0.6 }, "albedo of walls, floors and ceilings" },
        { "wall", 1, { 0.2 }, "wall thickness, m" },
        { "seed", 1, { 1 }, "layout seed (doorways, sets per room, props, lamp places)" } } },
};
#define NLEVELS ((int)(sizeof g_levels / sizeof g_levels[0]))

/* Levels --all leaves out (generate them by name): big ones, and the door test variants
 * (tests/doors/test_door_combo.c makes them; in build/levels test_estate_plan would sweep
 * door_combo, whose DLS in a sealed room is culled vs --plan all by 13%: padding and
 * under-wall leak pixels, the class of tests/test_plan_reach.c's two_rooms case). */
static int on_demand(const LevelDef *L)
{
    return !strcmp(L->name, "estate") || !strcmp(L->name, "door_combo") ||
           !strcmp(L->name, "door_chain");
}

/* ------------------------------------------------------------------------ */
/* Lightmap UVs (optional): one square grid cell per quad                    */

static void assign_uv1(void)
{
    int res = PI_("uv1_res"), pad = PI_("uv1_pad");
    require(res >= 4 && pad >= 0, "uv1_res>=4, uv1_pad>=0");
    long nq = 0;
    for (int i = 0; i < S.nmesh; i++) nq += S.meshes[i].nv / 4;
    int n = 1;
    while ((long)n * n < nq) n++;
    int s = (res - pad * (n + 1)) / n; /* cell side in whole texels */
    if (s < 1)
        die("level %s: %ld quads do not fit a %dx%d uv1 atlas with %d texel padding", g_level->name, nq, res, res,
            pad);
    long q = 0;
    for (int i = 0; i < S.nmesh; i++) {
        Mesh *m = &S.meshes[i];
        m->uv = xrealloc(m->uv, (size_t)(m->nv > 0 ? m->nv : 1) * 2 * sizeof(float));
        for (int f = 0; f < m->nv / 4; f++, q++) {
            int col = (int)(q % n), row = (int)(q / n);
            double u0 = (double)(pad + col * (s + pad)) / res, v0 = (double)(pad + row * (s + pad)) / res;
            double u1 = u0 + (double)s / res, v1 = v0 + (double)s / res;
            float *t = m->uv + 8 * f;
            t[0] = (float)u0; t[1] = (float)v0;
            t[2] = (float)u1; t[3] = (float)v0;
            t[4] = (float)u1; t[5] = (float)v1;
            t[6] = (float)u0; t[7] = (float)v1;
        }
    }
}

/* ------------------------------------------------------------------------ */
/* glTF writer                                                               */

typedef struct { char *s; size_t n, cap; } Buf;

static void bprintf(Buf *b, const char *fmt, ...)
{
    for (;;) {
        va_list ap;
        va_start(ap, fmt);
        size_t room = b->cap - b->n;
        int k = vsnprintf(b->s ? b->s + b->n : NULL, room, fmt, ap);
        va_end(ap);
        if (k < 0) die("internal: formatting failed");
        if ((size_t)k < room) { b->n += (size_t)k; return; }
        b->cap = (b->cap + (size_t)k + 1) * 2;
        b->s = xrealloc(b->s, b->cap);
    }
}

static void bbytes(Buf *b, const void *p, size_t n)
{
    if (b->n + n > b->cap) {
        b->cap = (b->n + n) * 2;
        b->s = xrealloc(b->s, b->cap);
    }
    memcpy(b->s + b->n, p, n);
    b->n += n;
}

/* Number in the shortest form that parses back to exactly v (so accessor
 * min/max equal the stored float32 values, whether read as float or double). */
static void bnum(Buf *b, double v)
{
    if (!isfinite(v)) die("internal: non-finite number in output");
    if (v == 0.0) v = 0.0; /* no "-0" */
    char tmp[40];
    int p0 = fabs(v) >= 1.0 && fabs(v) < 1e15 ? (int)floor(log10(fabs(v))) + 1 : 1; /* no 1e+01 */
    for (int prec = p0; prec <= 17; prec++) { /* shortest text that reads back exactly */
        snprintf(tmp, sizeof tmp, "%.*g", prec, v);
        if (strtod(tmp, NULL) == v) break;
    }
    bprintf(b, "%s", tmp);
}

static void bstr(Buf *b, const char *s)
{
    bprintf(b, "\"");
    for (; *s; s++) {
        unsigned char c = (unsigned char)*s;
        if (c == '"' || c == '\\') bprintf(b, "\\%c", c);
        else if (c < 0x20) bprintf(b, "\\u%04x", c);
        else bprintf(b, "%c", c);
    }
    bprintf(b, "\"");
}

static void bvec(Buf *b, const double *v, int n)
{
    bprintf(b, "[");
    for (int i = 0; i < n; i++) {
        if (i) bprintf(b, ", ");
        bnum(b, v[i]);
    }
    bprintf(b, "]");
}

typedef struct { size_t off, len; int target; } View;
typedef struct { int view, ctype, count; const char *type; int has_mm; double mn[3], mx[3]; } Accessor;

static void write_file(const char *path, const void *data, size_t n)
{
    FILE *f = fopen(path, "wb");
    if (!f) die("%s: cannot open for writing: %s", path, strerror(errno));
    if (n && fwrite(data, 1, n, f) != n) die("%s: write failed: %s", path, strerror(errno));
    if (fclose(f) != 0) die("%s: write failed: %s", path, strerror(errno));
}

static void mkdir_p(const char *dir)
{
    char tmp[4096];
    size_t n = strlen(dir);
    if (n == 0 || n >= sizeof tmp) die("bad output directory '%s'", dir);
    memcpy(tmp, dir, n + 1);
    for (size_t i = 1; i <= n; i++) {
        if (tmp[i] == '/' || tmp[i] == 0) {
            char c = tmp[i];
            tmp[i] = 0;
            if (mkdir(tmp, 0777) != 0 && errno != EEXIST) die("%s: cannot create directory: %s", tmp, strerror(errno));
            tmp[i] = c;
        }
    }
    struct stat st;
    if (stat(dir, &st) != 0 || !S_ISDIR(st.st_mode)) die("%s: not a directory", dir);
}

static void write_gltf(const char *dir, const char *base, const char *paramstr)
{
    Buf bin = { 0 }, js = { 0 };
    int nview = 0, nacc = 0;
    View *views = xrealloc(NULL, (size_t)(S.nmesh * 4 + 1) * sizeof *views);
    Accessor *accs = xrealloc(NULL, (size_t)(S.nmesh * 4 + 1) * sizeof *accs);
    int (*macc)[4] = xrealloc(NULL, (size_t)(S.nmesh + 1) * sizeof *macc); /* pos, nrm, uv, idx */

    for (int i = 0; i < S.nmesh; i++) {
        Mesh *m = &S.meshes[i];
        if (m->nv == 0 || m->ni == 0) die("internal: empty mesh %s", m->name);
        /* POSITION */
        Accessor *a = &accs[nacc];
        memset(a, 0, sizeof *a);
        a->view = nview; a->ctype = 5126; a->count = m->nv; a->type = "VEC3"; a->has_mm = 1;
        for (int c = 0; c < 3; c++) { a->mn[c] = INFINITY; a->mx[c] = -INFINITY; }
        for (int v = 0; v < m->nv; v++)
            for (int c = 0; c < 3; c++) {
                double x = m->pos[3 * v + c];
                if (x < a->mn[c]) a->mn[c] = x;
                if (x > a->mx[c]) a->mx[c] = x;
            }
        views[nview].off = bin.n; views[nview].len = (size_t)m->nv * 12; views[nview].target = 34962;
        bbytes(&bin, m->pos, views[nview].len);
        macc[i][0] = nacc++; nview++;
        /* NORMAL */
        a = &accs[nacc];
        memset(a, 0, sizeof *a);
        a->view = nview; a->ctype = 5126; a->count = m->nv; a->type = "VEC3";
        views[nview].off = bin.n; views[nview].len = (size_t)m->nv * 12; views[nview].target = 34962;
        bbytes(&bin, m->nrm, views[nview].len);
        macc[i][1] = nacc++; nview++;
        /* TEXCOORD_1 (optional) */
        macc[i][2] = -1;
        if (m->uv) {
            a = &accs[nacc];
            memset(a, 0, sizeof *a);
            a->view = nview; a->ctype = 5126; a->count = m->nv; a->type = "VEC2";
            views[nview].off = bin.n; views[nview].len = (size_t)m->nv * 8; views[nview].target = 34962;
            bbytes(&bin, m->uv, views[nview].len);
            macc[i][2] = nacc++; nview++;
        }
        /* indices */
        a = &accs[nacc];
        memset(a, 0, sizeof *a);
        a->view = nview; a->ctype = 5125; a->count = m->ni; a->type = "SCALAR";
        views[nview].off = bin.n; views[nview].len = (size_t)m->ni * 4; views[nview].target = 34963;
        bbytes(&bin, m->idx, views[nview].len);
        macc[i][3] = nacc++; nview++;
    }
    if (bin.n % 4) die("internal: buffer not 4-byte aligned");

    int any_emissive = 0;
    for (int i = 0; i < S.nmat; i++) any_emissive |= S.mats[i].emis_strength > 0;

    bprintf(&js, "{\n  \"asset\": {\"version\": \"2.0\", \"generator\": \"ubake-genlevel\", \"extras\": {\"genlevel_level\": ");
    bstr(&js, g_level->name);
    bprintf(&js, ", \"genlevel_params\": ");
    bstr(&js, paramstr);
    bprintf(&js, "}},\n");
    if (S.nlight || any_emissive) {
        bprintf(&js, "  \"extensionsUsed\": [");
        int k = 0;
        if (S.nlight) bprintf(&js, "%s\"KHR_lights_punctual\"", k++ ? ", " : "");
        if (any_emissive) bprintf(&js, "%s\"KHR_materials_emissive_strength\"", k++ ? ", " : "");
        bprintf(&js, "],\n");
    }
    if (S.nlight) {
        bprintf(&js, "  \"extensions\": {\"KHR_lights_punctual\": {\"lights\": [\n");
        for (int i = 0; i < S.nlight; i++) {
            Light *l = &S.lights[i];
            bprintf(&js, "    {\"name\": ");
            bstr(&js, l->name);
            bprintf(&js, ", \"type\": \"%s\", \"color\": ", l->type == LIGHT_POINT ? "point" : "directional");
            bvec(&js, l->color, 3);
            bprintf(&js, ", \"intensity\": ");
            bnum(&js, l->intensity);
            bprintf(&js, "}%s\n", i + 1 < S.nlight ? "," : "");
        }
        bprintf(&js, "  ]}},\n");
    }
    bprintf(&js, "  \"scene\": 0,\n  \"scenes\": [{\"name\": ");
    bstr(&js, base);
    bprintf(&js, ", \"nodes\": [");
    for (int i = 0; i < S.nnode; i++) bprintf(&js, "%s%d", i ? ", " : "", i);
    bprintf(&js, "]");
    {
        double ts = P("texel_size"), gs = P("glg_spacing");
        int k = 0;
        if (S.has_sky || ts > 0 || gs > 0) {
            bprintf(&js, ", \"extras\": {");
            if (S.has_sky) { bprintf(&js, "\"ubake_sky\": "); bvec(&js, S.sky, 3); k++; }
            if (ts > 0) { bprintf(&js, "%s\"ubake_texel_size\": ", k++ ? ", " : ""); bnum(&js, ts); }
            if (gs > 0) { bprintf(&js, "%s\"ubake_glg_spacing\": ", k++ ? ", " : ""); bnum(&js, gs); }
            bprintf(&js, "}");
        }
    }
    bprintf(&js, "}],\n  \"nodes\": [\n");
    for (int i = 0; i < S.nnode; i++) {
        Node *n = &S.nodes[i];
        bprintf(&js, "    {\"name\": ");
        bstr(&js, n->name);
        if (n->mesh >= 0) bprintf(&js, ", \"mesh\": %d", n->mesh);
        if (n->has_t) { bprintf(&js, ", \"translation\": "); bvec(&js, n->t, 3); }
        if (n->has_r) { bprintf(&js, ", \"rotation\": "); bvec(&js, n->r, 4); }
        if (n->light >= 0)
            bprintf(&js, ", \"extensions\": {\"KHR_lights_punctual\": {\"light\": %d}}", n->light);
        if (n->nex) {
            bprintf(&js, ", \"extras\": {");
            for (int k = 0; k < n->nex; k++) {
                if (k) bprintf(&js, ", ");
                bstr(&js, n->ex[k].key);
                bprintf(&js, ": ");
                bstr(&js, n->ex[k].val);
            }
            bprintf(&js, "}");
        }
        bprintf(&js, "}%s\n", i + 1 < S.nnode ? "," : "");
    }
    bprintf(&js, "  ],\n  \"meshes\": [\n");
    for (int i = 0; i < S.nmesh; i++) {
        bprintf(&js, "    {\"name\": ");
        bstr(&js, S.meshes[i].name);
        bprintf(&js, ", \"primitives\": [{\"attributes\": {\"POSITION\": %d, \"NORMAL\": %d", macc[i][0], macc[i][1]);
        if (macc[i][2] >= 0)
            bprintf(&js, ", \"TEXCOORD_0\": %d, \"TEXCOORD_1\": %d", macc[i][2], macc[i][2]);
        bprintf(&js, "}, \"indices\": %d, \"material\": %d, \"mode\": 4}]}%s\n", macc[i][3], S.meshes[i].mat,
                i + 1 < S.nmesh ? "," : "");
    }
    bprintf(&js, "  ],\n  \"materials\": [\n");
    for (int i = 0; i < S.nmat; i++) {
        Material *m = &S.mats[i];
        double bc[4] = { m->base[0], m->base[1], m->base[2], 1.0 };
        bprintf(&js, "    {\"name\": ");
        bstr(&js, m->name);
        bprintf(&js, ", \"pbrMetallicRoughness\": {\"baseColorFactor\": ");
        bvec(&js, bc, 4);
        bprintf(&js, ", \"metallicFactor\": 0, \"roughnessFactor\": 1}");
        if (m->emis_strength > 0) {
            bprintf(&js, ", \"emissiveFactor\": ");
            bvec(&js, m->emis_color, 3);
            bprintf(&js, ", \"extensions\": {\"KHR_materials_emissive_strength\": {\"emissiveStrength\": ");
            bnum(&js, m->emis_strength);
            bprintf(&js, "}}");
        }
        bprintf(&js, ", \"doubleSided\": false}%s\n", i + 1 < S.nmat ? "," : "");
    }
    bprintf(&js, "  ],\n  \"accessors\": [\n");
    for (int i = 0; i < nacc; i++) {
        Accessor *a = &accs[i];
        bprintf(&js, "    {\"bufferView\": %d, \"byteOffset\": 0, \"componentType\": %d, \"count\": %d, \"type\": \"%s\"",
                a->view, a->ctype, a->count, a->type);
        if (a->has_mm) {
            bprintf(&js, ", \"min\": ");
            bvec(&js, a->mn, 3);
            bprintf(&js, ", \"max\": ");
            bvec(&js, a->mx, 3);
        }
        bprintf(&js, "}%s\n", i + 1 < nacc ? "," : "");
    }
    bprintf(&js, "  ],\n  \"bufferViews\": [\n");
    for (int i = 0; i < nview; i++)
        bprintf(&js, "    {\"buffer\": 0, \"byteOffset\": %zu, \"byteLength\": %zu, \"target\": %d}%s\n", views[i].off,
                views[i].len, views[i].target, i + 1 < nview ? "," : "");
    bprintf(&js, "  ],\n  \"buffers\": [{\"byteLength\": %zu, \"uri\": ", bin.n);
    {
        char uri[512];
        snprintf(uri, sizeof uri, "%s.bin", base);
        bstr(&js, uri);
    }
    bprintf(&js, "}]\n}\n");

    char path[4608];
    mkdir_p(dir);
    snprintf(path, sizeof path, "%s/%s.bin", dir, base);
    write_file(path, bin.s, bin.n);
    snprintf(path, sizeof path, "%s/%s.gltf", dir, base);
    write_file(path, js.s, js.n);

    free(bin.s); free(js.s); free(views); free(accs); free(macc);
}

/* ------------------------------------------------------------------------ */
/* Driver                                                                    */

static const LevelDef *find_level(const char *name)
{
    for (int i = 0; i < NLEVELS; i++)
        if (!strcmp(g_levels[i].name, name)) return &g_levels[i];
    return NULL;
}

static void print_params(FILE *f, const LevelDef *L, int with_common)
{
    int n = level_nparams(L) + (with_common ? NCOMMON : 0);
    for (int i = 0; i < n; i++) {
        const ParamDef *d = param_def(L, i);
        char def[96];
        if (d->n == 3) snprintf(def, sizeof def, "%g,%g,%g", d->def[0], d->def[1], d->def[2]);
        else snprintf(def, sizeof def, "%g", d->def[0]);
        fprintf(f, "      %-14s = %-13s %s\n", d->key, def, d->help);
    }
}

static void usage(FILE *f)
{
    fprintf(f,
            "usage: %s --all -o DIR                  write every level as DIR/NAME.gltf + DIR/NAME.bin\n"
            "                                           (but estate, big: by name only)\n"
            "       %s NAME -o DIR [--param k=v ...] [--name BASE]\n"
            "                                           one level (output DIR/BASE.gltf, BASE defaults to NAME)\n"
            "       %s --list                        level names\n"
            "       %s [NAME] --help                 this text (or one level's parameters)\n"
            "levels:\n",
            g_prog, g_prog, g_prog, g_prog);
    for (int i = 0; i < NLEVELS; i++) {
        fprintf(f, "  %s: %s\n", g_levels[i].name, g_levels[i].purpose);
        print_params(f, &g_levels[i], 0);
    }
    fprintf(f, "parameters accepted by every level:\n");
    for (int i = 0; i < NCOMMON; i++) {
        const ParamDef *d = &common_params[i];
        fprintf(f, "      %-14s = %-13g %s\n", d->key, d->def[0], d->help);
    }
}

static void generate(const LevelDef *L, const char *dir, const char *base, const char *paramstr)
{
    g_level = L;
    scene_reset();
    L->build();
    if (PI_("llg_prop")) {
        const double *at = pv("llg_prop_at"), *sz = pv("llg_prop_size");
        require(sz[0] > 0 && sz[1] > 0 && sz[2] > 0, "llg_prop_size > 0");
        int mat = material("llg_prop", 0.6, 0.6, 0.6, 0);
        box_node("llg_prop", mat, v3(at[0] - 0.5 * sz[0], at[1], at[2] - 0.5 * sz[2]),
                 v3(at[0] + 0.5 * sz[0], at[1] + sz[1], at[2] + 0.5 * sz[2]));
        node_extra(&S.nodes[S.nnode - 1], "ubake_receiver", "llg");
    }
    if (PI_("lights_dls"))
        for (int i = 0; i < S.nnode; i++) {
            Node *n = &S.nodes[i];
            int has = 0;
            for (int k = 0; k < n->nex; k++) has |= !strcmp(n->ex[k].key, "ubake_dls");
            if (n->light >= 0 && !has) node_extra(n, "ubake_dls", "lights");
        }
    if (PI_("uv1")) assign_uv1();
    write_gltf(dir, base, paramstr);
    scene_reset();
}

int main(int argc, char **argv)
{
    const char *outdir = NULL, *name = NULL, *base = NULL;
    int all = 0, help = 0, list = 0;
    const char **kvs = xrealloc(NULL, (size_t)argc * sizeof *kvs);
    int nkv = 0;

    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "--all")) all = 1;
        else if (!strcmp(a, "--help") || !strcmp(a, "-h")) help = 1;
        else if (!strcmp(a, "--list")) list = 1;
        else if (!strcmp(a, "-o") || !strcmp(a, "--out")) {
            if (++i >= argc) die("%s needs a directory", a);
            outdir = argv[i];
        } else if (!strcmp(a, "--param") || !strcmp(a, "-p")) {
            if (++i >= argc) die("%s needs key=value", a);
            kvs[nkv++] = argv[i];
        } else if (!strncmp(a, "--param=", 8)) kvs[nkv++] = a + 8;
        else if (!strcmp(a, "--name")) {
            if (++i >= argc) die("--name needs a base name");
            base = argv[i];
        } else if (a[0] == '-') die("unknown option '%s' (try --help)", a);
        else if (strchr(a, '=')) kvs[nkv++] = a;
        else if (!name) name = a;
        else die("more than one level name given ('%s' and '%s')", name, a);
    }

    if (help) {
        if (name) {
            const LevelDef *L = find_level(name);
            if (!L) die("unknown level '%s' (try --list)", name);
            printf("%s: %s\n  parameters (--param key=value):\n", L->name, L->purpose);
            print_params(stdout, L, 1);
        } else usage(stdout);
        free(kvs);
        return 0;
    }
    if (list) {
        for (int i = 0; i < NLEVELS; i++) printf("%s\n", g_levels[i].name);
        free(kvs);
        return 0;
    }
    if (!outdir) die("missing -o DIR (try --help)");
    if (all) {
        if (name || nkv || base) die("--all takes no level name, --param or --name");
        for (int i = 0; i < NLEVELS; i++) {
            if (on_demand(&g_levels[i])) continue;
            params_defaults(&g_levels[i]);
            generate(&g_levels[i], outdir, g_levels[i].name, "");
        }
        free(kvs);
        return 0;
    }
    if (!name) die("missing level name or --all (try --help)");
    const LevelDef *L = find_level(name);
    if (!L) die("unknown level '%s' (try --list)", name);
    if (base && (!*base || strchr(base, '/'))) die("bad --name '%s'", base);
    params_defaults(L);
    Buf ps = { 0 };
    bprintf(&ps, "%s", "");
    for (int i = 0; i < nkv; i++) {
        params_set(L, kvs[i]);
        bprintf(&ps, "%s%s", i ? " " : "", kvs[i]);
    }
    generate(L, outdir, base ? base : L->name, ps.s);
    free(ps.s);
    free(kvs);
    return 0;
}
