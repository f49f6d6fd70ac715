/* tests/test_sah.c - the SAH evaluator, bvh_sah.

   Hand-built trees with known boxes; the expected values are worked out in the comments with
     SAH = Ci * sum_interior A(n)/A(root) + Cl * sum_leaves A(n)/A(root)
           + Ct * sum_leaves A(n) N(n)/A(root)
   where A is the surface area (the ratio is the same with half areas: dx*dy + dy*dz + dz*dx,
   used below). Then properties of built trees: an independent evaluation in double agrees, and
   PLOC's SAH collapse never makes the SAH worse than the uncollapsed tree. */
#define BVH_IMPLEMENTATION
#define BVH__MIN_PRIMS_PER_THREAD 1u /* small test inputs still take the threaded paths */
#include "bvh.h"
#include "test_util.h"

static bvh_node node(float x0, float y0, float z0, float x1, float y1, float z1, uint32_t index, uint32_t count) {
    bvh_node n;
    n.min = tu_v3(x0, y0, z0);
    n.max = tu_v3(x1, y1, z1);
    n.index = index;
    n.count = count;
    return n;
}
static bvh_tree tree_of(bvh_node *nodes, uint32_t node_count, uint32_t *prims, uint32_t refs) {
    bvh_tree t;
    memset(&t, 0, sizeof t);
    t.nodes = nodes;
    t.node_count = node_count;
    t.prims = prims;
    t.ref_count = refs;
    t.prim_count = refs;
    t.builder = BVH_BUILDER_TOP_DOWN;
    return t;
}
static double sah(const bvh_tree *t, float ci, float cl, float ct) {
    bvh_costs c;
    double out = -1.0;
    c.interior = ci;
    c.leaf = cl;
    c.triangle = ct;
    assert_int_equal(bvh_sah(t, &c, &out), BVH_SUCCESS);
    return out;
}
static void assert_close(double got, double want) {
    if (!(fabs(got - want) <= 1e-9 * fabs(want) + 1e-12)) fail_msg("SAH %.17g, expected %.17g", got, want);
}

/* One leaf, box [0,1]x[0,2]x[0,3], 4 primitives. A(leaf)/A(root) = 1, no interior node:
   SAH = Cl * 1 + Ct * 1 * 4.  (1,0,1): 4.  (1,1,1): 5.  (2,0.5,3): 0.5 + 12 = 12.5. */
static void single_leaf(void **state) {
    uint32_t prims[4] = {0, 1, 2, 3};
    bvh_node n[1];
    bvh_tree t;
    double out = -1.0;
    (void)state;
    n[0] = node(0, 0, 0, 1, 2, 3, 0, 4);
    t = tree_of(n, 1, prims, 4);
    assert_close(sah(&t, 1, 0, 1), 4.0);
    assert_close(sah(&t, 1, 1, 1), 5.0);
    assert_close(sah(&t, 2, 0.5f, 3), 12.5);
    /* NULL costs and all-zero costs both mean (1, 0, 1) */
    assert_int_equal(bvh_sah(&t, NULL, &out), BVH_SUCCESS);
    assert_close(out, 4.0);
    assert_close(sah(&t, 0, 0, 0), 4.0);
}

/* Root [0,4]x[0,2]x[0,2]: half area 4*2 + 2*2 + 2*4 = 20 (interior).
   Left leaf [0,1]^3: 3, 1 primitive.  Right leaf [2,4]x[0,2]x[0,2]: 4 + 4 + 4 = 12, 3 primitives.
   interior sum 20/20 = 1; leaf sum (3 + 12)/20 = 0.75; leaf area x count (3*1 + 12*3)/20 = 1.95.
   (1,0,1): 1 + 1.95 = 2.95.  (1,1,1): 1 + 0.75 + 1.95 = 3.7.  (2,0.5,3): 2 + 0.375 + 5.85 = 8.225. */
static void root_two_leaves(void **state) {
    uint32_t prims[4] = {0, 1, 2, 3};
    bvh_node n[3];
    bvh_tree t;
    (void)state;
    n[0] = node(0, 0, 0, 4, 2, 2, 1, 0);
    n[1] = node(0, 0, 0, 1, 1, 1, 0, 1);
    n[2] = node(2, 0, 0, 4, 2, 2, 1, 3);
    t = tree_of(n, 3, prims, 4);
    assert_close(sah(&t, 1, 0, 1), 2.95);
    assert_close(sah(&t, 1, 1, 1), 3.7);
    assert_close(sah(&t, 2, 0.5f, 3), 8.225);
}

/* Three levels. R [0,8]x[0,4]x[0,2]: 32 + 8 + 16 = 56 (interior), children A and B.
   A [0,4]x[0,4]x[0,2]: 16 + 8 + 8 = 32 (interior), children C and D.
   B [6,8]x[0,1]x[0,1]: 2 + 1 + 2 = 5, leaf of 2.  C [0,1]^3: 3, leaf of 1.
   D [2,4]x[2,4]x[0,2]: 4 + 4 + 4 = 12, leaf of 5.
   interior (56 + 32)/56 = 88/56; leaves (5 + 3 + 12)/56 = 20/56; area x count (10 + 3 + 60)/56 = 73/56.
   (1,0,1): 161/56.  (1,1,1): 181/56.  (2,0.5,3): (176 + 10 + 219)/56 = 405/56. */
static void three_levels(void **state) {
    uint32_t prims[8] = {0, 1, 2, 3, 4, 5, 6, 7};
    bvh_node n[5];
    bvh_tree t;
    (void)state;
    n[0] = node(0, 0, 0, 8, 4, 2, 1, 0); /* R */
    n[1] = node(0, 0, 0, 4, 4, 2, 3, 0); /* A */
    n[2] = node(6, 0, 0, 8, 1, 1, 6, 2); /* B */
    n[3] = node(0, 0, 0, 1, 1, 1, 0, 1); /* C */
    n[4] = node(2, 2, 0, 4, 4, 2, 1, 5); /* D */
    t = tree_of(n, 5, prims, 8);
    assert_close(sah(&t, 1, 0, 1), 161.0 / 56.0);
    assert_close(sah(&t, 1, 1, 1), 181.0 / 56.0);
    assert_close(sah(&t, 2, 0.5f, 3), 405.0 / 56.0);
}

/* A root of zero area (every box the point (1,2,3)): each ratio counts as 1.
   Root interior, leaves of 2 and 3: SAH = Ci * 1 + Cl * 2 + Ct * (2 + 3).
   (1,0,1): 6.  (1,1,1): 8.  (2,0.5,3): 2 + 1 + 15 = 18.
   A segment [0,5]x{0}x{0} also has zero area (two zero extents): the same values. */
static void zero_area_root(void **state) {
    uint32_t prims[5] = {0, 1, 2, 3, 4};
    bvh_node n[3];
    bvh_tree t;
    (void)state;
    n[0] = node(1, 2, 3, 1, 2, 3, 1, 0);
    n[1] = node(1, 2, 3, 1, 2, 3, 0, 2);
    n[2] = node(1, 2, 3, 1, 2, 3, 2, 3);
    t = tree_of(n, 3, prims, 5);
    assert_close(sah(&t, 1, 0, 1), 6.0);
    assert_close(sah(&t, 1, 1, 1), 8.0);
    assert_close(sah(&t, 2, 0.5f, 3), 18.0);
    n[0] = node(0, 0, 0, 5, 0, 0, 1, 0);
    n[1] = node(0, 0, 0, 2, 0, 0, 0, 2);
    n[2] = node(3, 0, 0, 5, 0, 0, 2, 3);
    assert_close(sah(&t, 1, 0, 1), 6.0);
    assert_close(sah(&t, 2, 0.5f, 3), 18.0);
}

/* An empty tree has SAH 0; bad arguments are refused. */
static void empty_tree_and_errors(void **state) {
    bvh_tree t;
    bvh_costs c;
    double out = -1.0;
    bvh_node n[1];
    uint32_t prims[1] = {0};
    (void)state;
    memset(&t, 0, sizeof t);
    assert_int_equal(bvh_sah(&t, NULL, &out), BVH_SUCCESS);
    assert_true(out == 0.0);
    out = -1.0;
    assert_close(sah(&t, 2, 0.5f, 3), 0.0);
    n[0] = node(0, 0, 0, 1, 1, 1, 0, 1);
    t = tree_of(n, 1, prims, 1);
    assert_int_equal(bvh_sah(NULL, NULL, &out), BVH_ERROR_INVALID_ARGUMENT);
    assert_int_equal(bvh_sah(&t, NULL, NULL), BVH_ERROR_INVALID_ARGUMENT);
    c.interior = 1;
    c.leaf = -1;
    c.triangle = 1;
    assert_int_equal(bvh_sah(&t, &c, &out), BVH_ERROR_INVALID_ARGUMENT);
    c.leaf = 0;
    c.interior = NAN;
    assert_int_equal(bvh_sah(&t, &c, &out), BVH_ERROR_INVALID_ARGUMENT);
    c.interior = 1;
    c.triangle = BVH_INF;
    assert_int_equal(bvh_sah(&t, &c, &out), BVH_ERROR_INVALID_ARGUMENT);
}

/* The SAH of a tree, evaluated here in double by walking from the root. */
static double reference_sah(const bvh_tree *t, double ci, double cl, double ct) {
    uint32_t stack[2 * BVH_MAX_DEPTH + 4], sp = 0;
    double root, total = 0.0;
    const bvh_node *r = &t->nodes[0];
    root = ((double)r->max.x - r->min.x) * ((double)r->max.y - r->min.y) +
           ((double)r->max.y - r->min.y) * ((double)r->max.z - r->min.z) +
           ((double)r->max.z - r->min.z) * ((double)r->max.x - r->min.x);
    stack[sp++] = 0;
    while (sp) {
        const bvh_node *n = &t->nodes[stack[--sp]];
        double dx = (double)n->max.x - n->min.x, dy = (double)n->max.y - n->min.y, dz = (double)n->max.z - n->min.z;
        double a = root > 0.0 ? (dx * dy + dy * dz + dz * dx) / root : 1.0;
        if (n->count) {
            total += a * (cl + ct * n->count);
            continue;
        }
        total += a * ci;
        stack[sp++] = n->index;
        stack[sp++] = n->index + 1;
    }
    return total;
}

/* bvh_sah agrees with the walk above on every builder's trees (float areas: 1e-5 relative). */
static void built_trees_agree_with_reference(void **state) {
    static const float costs[3][3] = {{1, 0, 1}, {1, 1, 1}, {2, 0.5f, 3}};
    int b, k, scene;
    (void)state;
    for (scene = 0; scene < 3; scene++) {
        tu_scene s;
        if (scene == 0)
            tu_scene_random(&s, 2000, 0x534148ULL);
        else if (scene == 1)
            tu_scene_grid(&s);
        else
            tu_scene_strided32(&s);
        for (b = 0; b < TU_BUILDER_COUNT; b++) {
            bvh_tree t;
            tu_build(&s, tu_builder(b), &t);
            for (k = 0; k < 3; k++) {
                double got = sah(&t, costs[k][0], costs[k][1], costs[k][2]);
                double want = reference_sah(&t, costs[k][0], costs[k][1], costs[k][2]);
                if (!(fabs(got - want) <= 1e-5 * want))
                    fail_msg("%s/%s: bvh_sah %.9g, reference %.9g", s.name, bvh_builder_name(tu_builder(b)), got, want);
            }
            /* lower bound: every primitive is intersected once in a leaf no smaller than its box */
            assert_true(sah(&t, 1, 0, 1) > 0.0);
            bvh_free(&t);
        }
        tu_scene_free(&s);
    }
}

/* PLOC collapses subtrees into leaves where the SAH says a leaf is cheaper (bottom-up, so the
   choice is optimal for the clustering): with the costs it was built for, the collapsed tree's SAH
   is never above the one of the same clustering without collapse (max_leaf_size 1). Without the
   memory budget (desc.ploc.max_bytes_per_prim), which trades SAH for bytes on random triangles. */
static void ploc_collapse_never_worse(void **state) {
    static const float costs[4][3] = {{1, 0, 1}, {1, 1, 1}, {2, 0.5f, 3}, {1, 0, 4}};
    tu_scene s;
    int k, scene;
    (void)state;
    for (scene = 0; scene < 2; scene++) {
        if (scene == 0)
            tu_scene_random(&s, 3000, 0x434f4cULL);
        else
            tu_scene_strided32(&s);
        for (k = 0; k < 4; k++) {
            bvh_tree flat, collapsed;
            bvh_build_desc d = tu_scene_desc(&s, BVH_BUILDER_PLOC);
            double a, b;
            d.costs.interior = costs[k][0];
            d.costs.leaf = costs[k][1];
            d.costs.triangle = costs[k][2];
            d.ploc.max_bytes_per_prim = BVH_OFF;
            d.max_leaf_size = 1;
            tu_build_valid(&s, &d, &flat);
            d.max_leaf_size = 0;
            tu_build_valid(&s, &d, &collapsed);
            a = sah(&collapsed, costs[k][0], costs[k][1], costs[k][2]);
            b = sah(&flat, costs[k][0], costs[k][1], costs[k][2]);
            print_message("%s costs (%g, %g, %g): collapsed %.4f, one triangle per leaf %.4f\n", s.name,
                          (double)costs[k][0], (double)costs[k][1], (double)costs[k][2], a, b);
            if (!(a <= b * (1.0 + 1e-5))) fail_msg("collapse made the SAH worse: %.9g > %.9g", a, b);
            assert_true(collapsed.node_count <= flat.node_count);
            bvh_free(&flat);
            bvh_free(&collapsed);
        }
        tu_scene_free(&s);
    }
}

int main(void) {
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(single_leaf),
        cmocka_unit_test(root_two_leaves),
        cmocka_unit_test(three_levels),
        cmocka_unit_test(zero_area_root),
        cmocka_unit_test(empty_tree_and_errors),
        cmocka_unit_test(built_trees_agree_with_reference),
        cmocka_unit_test(ploc_collapse_never_worse),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
