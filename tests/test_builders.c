/* tests/test_builders.c - every builder makes a valid tree on every scene.

   For each scene of test_util.h and each builder: bvh_validate passes (against the triangles
   and against caller-side boxes), the statistics add up, the reference-ordered triangle copy is
   the input's, the same input gives the same tree twice; every builder hits the same primitives
   at the same distances as every other; ploc-parallel gives exactly ploc's tree (memcmp of nodes,
   references and triangles) on 1, 2, 3, 8 and all threads; leaf size, cost and option variants
   build valid trees; PLOC's SAH top at every setting hits as brute force does. */
#define BVH_IMPLEMENTATION
#define BVH__MIN_PRIMS_PER_THREAD 1u /* small test inputs still take the threaded paths */
#include "bvh.h"
#include "test_util.h"
#include "tree_diff.h"

/* The statistics agree with a walk over the tree done here. */
static void check_stats(const tu_scene *s, const bvh_tree *t, uint32_t max_leaf) {
    bvh_stats st;
    uint32_t i, leaves = 0, refs = 0;
    const char *name = bvh_builder_name(t->builder);
    assert_int_equal(bvh_get_stats(t, &st), BVH_SUCCESS);
    for (i = 0; i < t->node_count; i++)
        if (t->nodes[i].count) {
            leaves++;
            refs += t->nodes[i].count;
        }
    if (st.nodes != t->node_count || st.refs != t->ref_count || st.leaves != leaves || refs != t->ref_count ||
        st.bytes != (size_t)st.nodes * 32 + (size_t)st.refs * 4 || st.triangle_bytes != (size_t)st.refs * 36 ||
        (t->node_count && st.leaves * 2 - 1 != st.nodes) || st.max_depth > BVH_MAX_DEPTH ||
        st.max_leaf_size > max_leaf || (t->node_count && (st.max_depth < 1 || st.max_leaf_size < 1)))
        fail_msg(
            "%s/%s: stats nodes %u leaves %u (walk %u) refs %u (leaf sum %u, tree %u) depth %u max leaf %u (limit %u) "
            "bytes %zu triangle bytes %zu",
            s->name, name, st.nodes, st.leaves, leaves, st.refs, refs, t->ref_count, st.max_depth, st.max_leaf_size,
            max_leaf, st.bytes, st.triangle_bytes);
}

/* Fields, triangle copy and root box of a tree built from scene s. */
static void check_tree(const tu_scene *s, const float *tris, const bvh_aabb *boxes, const bvh_tree *t, bvh_builder b) {
    bvh_validation rep;
    bvh_aabb root = bvh_tree_bounds(t), bounds = tu_scene_bounds(s);
    uint32_t k;
    const char *name = bvh_builder_name(b);
    assert_int_equal(t->builder, b);
    assert_int_equal(t->prim_count, s->tri_count);
    assert_int_equal(t->excluded, 0);
    assert_non_null(t->tris);
    if (b == BVH_BUILDER_SAH_MIDPOINT)
        assert_true(t->ref_count >= s->tri_count); /* it may split references */
    else
        assert_int_equal(t->ref_count, s->tri_count);
    if (bvh_validate(t, boxes, &rep) != BVH_SUCCESS)
        fail_msg("%s/%s: bvh_validate with caller boxes: %s (node %u)", s->name, name, rep.message, rep.node);
    for (k = 0; k < t->ref_count; k++)
        if (memcmp(t->tris + 9 * (size_t)k, tris + 9 * (size_t)t->prims[k], 9 * sizeof(float)) != 0)
            fail_msg("%s/%s: tree.tris of reference %u is not triangle %u", s->name, name, k, t->prims[k]);
    assert_true(bvh_aabb_contains(root, bounds));
    if (t->ref_count == s->tri_count) /* no splits: the root is the union of the triangle boxes */
        assert_true(root.min.x == bounds.min.x && root.min.y == bounds.min.y && root.min.z == bounds.min.z &&
                    root.max.x == bounds.max.x && root.max.y == bounds.max.y && root.max.z == bounds.max.z);
}

/* The tree d builds on each of the thread counts is t, every array of it (tag: the row's suffix
   in the message). */
static void same_on_threads(const tu_scene *s, bvh_build_desc d, const bvh_tree *t, const uint32_t *threads, size_t n,
                            const char *tag) {
    size_t th;
    for (th = 0; th < n; th++) {
        bvh_tree again;
        const char *diff;
        d.threads = threads[th];
        tu_build_valid(s, &d, &again);
        diff = tree_diff(t, &again);
        if (diff)
            fail_msg("%s/%s%s: %s differ on %u threads", s->name, bvh_builder_name(d.builder), tag, diff, threads[th]);
        bvh_free(&again);
    }
}

/* The state's scene (0 when it is not there: the test is skipped), its triangles and a box
   per triangle (both malloc'd). */
static int scene_with_boxes(void **state, tu_scene *s, float **tris, bvh_aabb **boxes) {
    uint32_t i;
    if (!tu_scene_make(tu_state_id(state), s)) {
        skip();
        return 0;
    }
    *tris = tu_scene_tris(s);
    *boxes = (bvh_aabb *)malloc(s->tri_count * sizeof **boxes);
    assert_non_null(*boxes);
    for (i = 0; i < s->tri_count; i++) (*boxes)[i] = tu_tri_box(*tris + 9 * (size_t)i);
    return 1;
}

static void every_builder_valid(void **state) {
    static const uint32_t threads[] = {1, 2, 3, 8, 0};
    int b;
    tu_scene s;
    float *tris;
    bvh_aabb *boxes;
    if (!scene_with_boxes(state, &s, &tris, &boxes)) return;
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        bvh_tree t;
        bvh_build_desc d = tu_scene_desc(&s, tu_builder(b));
        tu_build_valid(&s, &d, &t);
        check_tree(&s, tris, boxes, &t, tu_builder(b));
        check_stats(&s, &t, tu_default_leaf(tu_builder(b)));
        /* deterministic: the same input gives the same tree, every array of it, on any threads */
        same_on_threads(&s, d, &t, threads, sizeof threads / sizeof threads[0], "");
        bvh_free(&t);
    }
    free(boxes);
    free(tris);
    tu_scene_free(&s);
}

/* Every builder hits the same number of rays, and in fact the same primitives at the same t. */
static void builders_agree(void **state) {
    enum { RAYS = 4000 };
    int id = tu_state_id(state), b;
    tu_scene s;
    float *tris;
    bvh_ray *rays;
    bvh_hit *first, h;
    size_t i, count[TU_BUILDER_COUNT], differ[TU_BUILDER_COUNT];
    if (!tu_scene_make(id, &s)) {
        skip();
        return;
    }
    rays = (bvh_ray *)malloc(RAYS * sizeof *rays);
    first = (bvh_hit *)malloc(RAYS * sizeof *first);
    assert_true(rays && first);
    tris = tu_scene_tris(&s);
    tu_make_rays(tris, s.tri_count, 0x6167726565ULL + (uint64_t)id, rays, RAYS);
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        bvh_tree t;
        tu_build(&s, tu_builder(b), &t);
        count[b] = differ[b] = 0;
        for (i = 0; i < RAYS; i++) {
            bvh_hit *out = b == 0 ? &first[i] : &h;
            count[b] += (size_t)bvh_intersect(&t, &rays[i], out);
            if (b > 0 && !tu_hit_equal(&h, &first[i]) && differ[b]++ < 2) {
                print_error("%s: %s and %s differ on ray %zu\n", s.name, bvh_builder_name(tu_builder(0)),
                            bvh_builder_name(tu_builder(b)), i);
                tu_print_ray(&rays[i]);
                tu_print_hit(bvh_builder_name(tu_builder(0)), &first[i]);
                tu_print_hit(bvh_builder_name(tu_builder(b)), &h);
            }
        }
        bvh_free(&t);
    }
    for (b = 0; b < TU_BUILDER_COUNT; b++)
        print_message("%-18s %-14s %zu of %d rays hit, %zu differ from %s\n", s.name, bvh_builder_name(tu_builder(b)),
                      count[b], RAYS, differ[b], bvh_builder_name(tu_builder(0)));
    for (b = 1; b < TU_BUILDER_COUNT; b++) {
        assert_int_equal(count[b], count[0]);
        assert_int_equal(differ[b], 0);
    }
    free(rays);
    free(first);
    free(tris);
    tu_scene_free(&s);
}

/* Two trees are the same: every public array (tree_diff.h). */
static void assert_same_tree(const tu_scene *s, const bvh_tree *a, const bvh_tree *b, uint32_t threads) {
    const char *diff = tree_diff(a, b);
    if (diff)
        fail_msg("%s: ploc-parallel on %u threads differs from ploc in %s (%u/%u nodes, %u/%u refs)", s->name, threads,
                 diff, b->node_count, a->node_count, b->ref_count, a->ref_count);
}
static void ploc_parallel_same_tree(const tu_scene *s, const bvh_build_desc *base) {
    static const uint32_t threads[] = {1, 2, 3, 8, 0};
    bvh_build_desc d = *base;
    bvh_tree ploc, par;
    size_t k;
    d.builder = BVH_BUILDER_PLOC;
    tu_build_valid(s, &d, &ploc);
    d.builder = BVH_BUILDER_PLOC_PARALLEL;
    for (k = 0; k < sizeof threads / sizeof threads[0]; k++) {
        d.threads = threads[k];
        tu_build_valid(s, &d, &par);
        assert_same_tree(s, &ploc, &par, threads[k]);
        bvh_free(&par);
    }
    d.builder = BVH_BUILDER_DEFAULT; /* the default builder is ploc-parallel */
    d.threads = 3;
    tu_build_valid(s, &d, &par);
    assert_int_equal(par.builder, BVH_BUILDER_PLOC_PARALLEL);
    assert_same_tree(s, &ploc, &par, 3);
    bvh_free(&par);
    bvh_free(&ploc);
}
static void ploc_parallel_equals_ploc(void **state) {
    int id = tu_state_id(state);
    tu_scene s;
    bvh_build_desc d;
    if (!tu_scene_make(id, &s)) {
        skip();
        return;
    }
    d = tu_scene_desc(&s, BVH_BUILDER_PLOC);
    ploc_parallel_same_tree(&s, &d);
    tu_scene_free(&s);
}
/* The same with other options: search radius, leaf size, costs (on scenes big enough for every
   thread to get clusters: 4 * radius + 256 per thread). */
static void ploc_parallel_equals_ploc_options(void **state) {
    static const uint32_t radius[] = {1, 2, 7, 256};
    static const uint32_t leaf[] = {1, 2, 255};
    tu_scene s;
    bvh_build_desc d;
    size_t k;
    (void)state;
    tu_scene_random(&s, 6000, 0x4f5054ULL);
    for (k = 0; k < sizeof radius / sizeof radius[0]; k++) {
        d = tu_scene_desc(&s, BVH_BUILDER_PLOC);
        d.ploc.radius = radius[k];
        ploc_parallel_same_tree(&s, &d);
    }
    for (k = 0; k < sizeof leaf / sizeof leaf[0]; k++) {
        d = tu_scene_desc(&s, BVH_BUILDER_PLOC);
        d.max_leaf_size = leaf[k];
        ploc_parallel_same_tree(&s, &d);
    }
    d = tu_scene_desc(&s, BVH_BUILDER_PLOC);
    d.costs.interior = 2.0f;
    d.costs.leaf = 0.5f;
    d.costs.triangle = 3.0f;
    ploc_parallel_same_tree(&s, &d);
    tu_scene_free(&s);
    tu_scene_grid(&s);
    d = tu_scene_desc(&s, BVH_BUILDER_PLOC);
    d.ploc.radius = 3;
    ploc_parallel_same_tree(&s, &d);
    tu_scene_free(&s);
}

/* Every ray hits in t what brute force (the culled oracle's `want`) hits, or misses with it. */
static void hits_as_brute_force(const tu_scene *s, const bvh_tree *t, const bvh_ray *rays, const bvh_hit *want,
                                size_t n, const char *option, uint32_t value) {
    size_t i;
    for (i = 0; i < n; i++) {
        bvh_hit h;
        int hit = bvh_intersect(t, &rays[i], &h), bf = want[i].prim != BVH_INVALID;
        if (hit != bf || (hit && !tu_hit_equal(&h, &want[i])))
            fail_msg("%s: %s %u: ray %zu differs from brute force", s->name, option, value, i);
    }
}

/* PLOC's SAH top (desc.ploc.top): off, at every other cut (2, 3), the default (8) and a late one
   (64) give valid trees with exactly the brute-force hits; ploc-parallel gives ploc's tree at
   every setting; the SAH top is used where it lowers the cost (random triangles) and never
   raises it above PLOC alone by more than rounding. */
static void ploc_top_variants(void **state) {
    enum { RAYS = 3000 };
    static const uint32_t tops[] = {BVH_OFF, 1, 2, 3, 0, 64};
    int scene;
    size_t k;
    (void)state;
    for (scene = 0; scene < 4; scene++) {
        tu_scene s;
        float *tris;
        bvh_ray *rays = (bvh_ray *)malloc(RAYS * sizeof *rays);
        bvh_hit *want = (bvh_hit *)malloc(RAYS * sizeof *want);
        double sah[sizeof tops / sizeof tops[0]];
        assert_true(rays && want);
        if (scene == 0)
            tu_scene_random(&s, 6000, 0x544f50ULL);
        else if (scene == 1)
            tu_scene_grid(&s);
        else if (scene == 2)
            tu_scene_duplicates(&s);
        else if (!tu_scene_bunny(&s)) {
            free(rays);
            free(want);
            continue;
        }
        tris = tu_scene_tris(&s);
        tu_make_rays(tris, s.tri_count, 0x746f70ULL + (uint64_t)scene, rays, RAYS);
        tu_oracle_run(tris, s.tri_count, rays, RAYS, want); /* brute force, once per scene */
        for (k = 0; k < sizeof tops / sizeof tops[0]; k++) {
            bvh_build_desc d = tu_scene_desc(&s, BVH_BUILDER_PLOC);
            bvh_tree t;
            d.ploc.top = tops[k];
            tu_build_valid(&s, &d, &t);
            check_stats(&s, &t, 8);
            assert_int_equal(bvh_sah(&t, NULL, &sah[k]), BVH_SUCCESS);
            hits_as_brute_force(&s, &t, rays, want, RAYS, "ploc_top", tops[k]);
            bvh_free(&t);
            if (scene < 3) ploc_parallel_same_tree(&s, &d);
            print_message("%-18s ploc_top %10u: SAH %.4f\n", s.name, tops[k], sah[k]);
            if (k > 0) assert_true(sah[k] <= sah[0] * 1.001);
        }
        if (scene == 0) assert_true(sah[4] < sah[0] * 0.99); /* the default top is taken and better */
        free(rays);
        free(want);
        free(tris);
        tu_scene_free(&s);
    }
}

/* PLOC's memory budget (desc.ploc.max_bytes_per_prim): random triangles, whose SAH-best leaves are
   one triangle each, give trees over 40 bytes per triangle without it; by default the tree fits
   in 40 and stays within 1% of it, at a higher but bounded SAH cost; a budget of 60 fits between
   the two; the smallest budget gives the smallest tree leaves of 8 allow; leaves of one triangle
   cannot fit, and the tree is then the unbudgeted one. Every tree is valid, hits as brute force
   does, and ploc-parallel gives ploc's tree on any thread count. */
static double tree_bytes_per_tri(const bvh_tree *t) {
    return ((double)t->node_count * sizeof(bvh_node) + (double)t->ref_count * sizeof(uint32_t)) / t->prim_count;
}
static void memory_budget(void **state) {
    enum { RAYS = 2000 };
    static const uint32_t sizes[] = {500, 5000, 40000};
    size_t z, i, k;
    (void)state;
    for (z = 0; z < sizeof sizes / sizeof sizes[0]; z++) {
        static const uint32_t budgets[] = {BVH_OFF, 0, 60, 1};
        tu_scene s;
        float *tris;
        bvh_ray *rays = (bvh_ray *)malloc(RAYS * sizeof *rays);
        bvh_hit *want = (bvh_hit *)malloc(RAYS * sizeof *want);
        double bytes[4], sah[4];
        assert_true(rays && want);
        tu_scene_random(&s, sizes[z], 0x4d454dULL + z);
        tris = tu_scene_tris(&s);
        tu_make_rays(tris, s.tri_count, 0x627564ULL + z, rays, RAYS);
        tu_oracle_run(tris, s.tri_count, rays, RAYS, want);
        for (k = 0; k < 4; k++) {
            bvh_build_desc d = tu_scene_desc(&s, BVH_BUILDER_PLOC);
            bvh_tree t;
            /* the default collapse's dearer interior node keeps random triangles under 40 bytes;
               the budget is tested where the SAH alone would go over it */
            d.costs.interior = 1.2f;
            d.costs.triangle = 1.0f;
            d.ploc.max_bytes_per_prim = budgets[k];
            tu_build_valid(&s, &d, &t);
            check_stats(&s, &t, 8);
            bytes[k] = tree_bytes_per_tri(&t);
            assert_int_equal(bvh_sah(&t, NULL, &sah[k]), BVH_SUCCESS);
            hits_as_brute_force(&s, &t, rays, want, RAYS, "budget", budgets[k]);
            if (k == 3) { /* the smallest tree: no subtree of 8 or fewer triangles is a node */
                for (i = 0; i < t.node_count; i++)
                    if (!t.nodes[i].count) {
                        const bvh_node *l = &t.nodes[t.nodes[i].index], *r = l + 1;
                        if (l->count && r->count) assert_true(l->count + r->count > 8);
                    }
            }
            bvh_free(&t);
            if (z == 0) ploc_parallel_same_tree(&s, &d);
            print_message("random:%-6u budget %10u: %.2f bytes/tri, SAH %.4f\n", sizes[z], budgets[k], bytes[k],
                          sah[k]);
        }
        assert_true(bytes[0] > 40.0); /* the budget has something to do */
        assert_true(bytes[1] <= 40.0 && bytes[1] >= 0.99 * 40.0 - 0.01);
        assert_true(bytes[2] <= 60.0 && bytes[2] > bytes[1]);
        assert_true(bytes[3] <= bytes[1]);
        assert_true(sah[1] >= sah[0] && sah[1] <= 1.06 * sah[0]); /* a bounded price for the bytes */
        assert_true(sah[2] <= sah[1]);
        free(rays);
        free(want);
        free(tris);
        tu_scene_free(&s);
    }
    { /* leaves of one triangle cannot fit in 40 bytes: the tree is then the unbudgeted one */
        tu_scene s;
        bvh_build_desc d;
        bvh_tree a, b;
        tu_scene_random(&s, 3000, 0x4f4e45ULL);
        d = tu_scene_desc(&s, BVH_BUILDER_PLOC);
        d.max_leaf_size = 1;
        tu_build_valid(&s, &d, &a);
        d.ploc.max_bytes_per_prim = BVH_OFF;
        tu_build_valid(&s, &d, &b);
        assert_int_equal(a.node_count, 2 * s.tri_count - 1);
        assert_int_equal(a.node_count, b.node_count);
        assert_memory_equal(a.nodes, b.nodes, a.node_count * sizeof(bvh_node));
        bvh_free(&a);
        bvh_free(&b);
        tu_scene_free(&s);
    }
}

/* Leaf size limits are kept: 1 (one triangle per leaf), 2, 3, 7, 255, on two scenes. */
static void leaf_sizes(void **state) {
    static const uint32_t leaf[] = {1, 2, 3, 7, 255};
    int scene, b;
    size_t k;
    (void)state;
    for (scene = 0; scene < 2; scene++) {
        tu_scene s;
        if (scene == 0)
            tu_scene_random(&s, 1000, 0x4c454146ULL);
        else
            tu_scene_duplicates(&s);
        for (b = 0; b < TU_BUILDER_COUNT; b++)
            for (k = 0; k < sizeof leaf / sizeof leaf[0]; k++) {
                bvh_tree t;
                bvh_build_desc d = tu_scene_desc(&s, tu_builder(b));
                d.max_leaf_size = leaf[k];
                tu_build_valid(&s, &d, &t);
                check_stats(&s, &t, leaf[k]);
                if (leaf[k] == 1 && t.ref_count == s.tri_count) assert_int_equal(t.node_count, 2 * s.tri_count - 1);
                bvh_free(&t);
            }
        tu_scene_free(&s);
    }
}

/* Build-time options: cost triples, ploc radius, split budget, thread counts - all valid. */
static void options_build_valid(void **state) {
    static const bvh_costs costs[] = {{1, 0, 1}, {1, 1, 1}, {2, 0.5f, 3}, {0, 0, 1}, {1, 0, 0}, {0, 5, 0}};
    static const float budgets[] = {(float)BVH_OFF, 0.0f, 0.01f, 0.5f, 1.0f};
    tu_scene s;
    int b;
    size_t k;
    (void)state;
    tu_scene_random(&s, 1500, 0x4f505453ULL);
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        bvh_tree t;
        for (k = 0; k < sizeof costs / sizeof costs[0]; k++) {
            bvh_build_desc d = tu_scene_desc(&s, tu_builder(b));
            d.costs = costs[k];
            tu_build_valid(&s, &d, &t);
            check_stats(&s, &t, tu_default_leaf(tu_builder(b)));
            bvh_free(&t);
        }
        for (k = 0; k < sizeof budgets / sizeof budgets[0]; k++) {
            bvh_build_desc d = tu_scene_desc(&s, tu_builder(b));
            d.sah_midpoint.split_budget = budgets[k];
            tu_build_valid(&s, &d, &t);
            if (tu_builder(b) == BVH_BUILDER_SAH_MIDPOINT && budgets[k] == (float)BVH_OFF)
                assert_int_equal(t.ref_count, s.tri_count); /* off: no splits */
            else if (tu_builder(b) == BVH_BUILDER_SAH_MIDPOINT && budgets[k] > 0.0f)
                assert_true(t.ref_count <= s.tri_count + (uint32_t)(budgets[k] * (float)s.tri_count) + 1);
            bvh_free(&t);
        }
        {
            bvh_build_desc d = tu_scene_desc(&s, tu_builder(b));
            d.threads = 1000; /* clamped to 256 */
            d.ploc.radius = 256;
            tu_build_valid(&s, &d, &t);
            bvh_free(&t);
        }
    }
    tu_scene_free(&s);
}

/* The Morton sort on its own (bvh__radix_sort_team): it must give the one stable order, keys
   ascending and equal keys in value order, on 1, 2 and 3 threads. Key patterns: spread over the
   top digit (one scatter, then each range in cache), one top digit (on several threads, the LSD
   passes instead), three top digits (ranges over a quarter: LSD on several threads), few
   distinct keys (ties), all equal; sizes around the insertion-sort threshold and larger. */
typedef struct sort_job {
    bvh__sort *s;
} sort_job;
static void sort_team_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    bvh__radix_sort_team(((sort_job *)arg)->s, tid, nt, team);
}
typedef struct sort_pair {
    uint64_t key;
    uint32_t val;
} sort_pair;
static int sort_pair_cmp(const void *a, const void *b) {
    const sort_pair *x = (const sort_pair *)a, *y = (const sort_pair *)b;
    if (x->key != y->key) return x->key < y->key ? -1 : 1;
    return x->val < y->val ? -1 : x->val > y->val;
}
static uint64_t sort_key(tu_rng *r, int pattern) {
    uint64_t lo = (uint64_t)tu_u32(r) << 32 | tu_u32(r);
    switch (pattern) {
    case 0:
        return lo >> 1; /* 63 random bits */
    case 1:
        return (uint64_t)0x5a5 << 52 | (lo & (((uint64_t)1 << 52) - 1)); /* one top digit */
    case 2:
        return (uint64_t)(1 + tu_below(r, 3)) << 53 | (lo >> 20); /* three top digits */
    case 3:
        return (uint64_t)tu_below(r, 5) << 40 | tu_below(r, 3); /* few distinct keys */
    default:
        return 42; /* all equal */
    }
}
static void morton_sort_alone(void **state) {
    static const size_t sizes[] = {1, 2, 15, 16, 17, 33, 257, 1000, 50000};
    const bvh_allocator al = {NULL, NULL, NULL};
    size_t z, i;
    int pattern;
    uint32_t nt;
    (void)state;
    for (pattern = 0; pattern < 5; pattern++)
        for (z = 0; z < sizeof sizes / sizeof sizes[0]; z++)
            for (nt = 1; nt <= 3; nt++) {
                size_t n = sizes[z];
                tu_rng r = tu_rng_make(0x736f7274ULL + (uint64_t)(pattern * 100 + (int)z));
                sort_pair *want = (sort_pair *)malloc(n * sizeof *want);
                bvh__sort s;
                sort_job job;
                s.n = n;
                s.keys = (uint64_t *)malloc(n * sizeof(uint64_t));
                s.keys_tmp = (uint64_t *)malloc(n * sizeof(uint64_t));
                s.vals = (uint32_t *)malloc(n * sizeof(uint32_t));
                s.vals_tmp = (uint32_t *)malloc(n * sizeof(uint32_t));
                s.hist = (uint32_t *)malloc((size_t)nt * BVH__RADIX_SIZE * sizeof(uint32_t));
                assert_true(want && s.keys && s.keys_tmp && s.vals && s.vals_tmp && s.hist);
                for (i = 0; i < n; i++) {
                    want[i].key = s.keys[i] = sort_key(&r, pattern);
                    want[i].val = s.vals[i] = (uint32_t)i;
                }
                qsort(want, n, sizeof *want, sort_pair_cmp);
                job.s = &s;
                assert_int_equal(bvh__team_run(&al, nt, sort_team_fn, &job), BVH_SUCCESS);
                for (i = 0; i < n; i++)
                    if (s.keys[i] != want[i].key || s.vals[i] != want[i].val)
                        fail_msg("pattern %d, %zu keys, %u threads: position %zu differs", pattern, n, nt, i);
                free(want);
                free(s.keys);
                free(s.keys_tmp);
                free(s.vals);
                free(s.vals_tmp);
                free(s.hist);
            }
}

/* The optimizer (desc.optimize) on every builder and scene: the tree is valid (with caller boxes
   too), its statistics add up, it is the same byte for byte on 1, 2, 3 and 8 threads, and on
   the bunny it costs less (SAH) than the builder's own tree for the builders whose trees it is
   meant for. */
static void optimizer_valid(void **state) {
    static const uint32_t threads[] = {2, 3, 8};
    int id = tu_state_id(state), b;
    tu_scene s;
    float *tris;
    bvh_aabb *boxes;
    if (!scene_with_boxes(state, &s, &tris, &boxes)) return;
    for (b = 0; b < TU_BUILDER_COUNT; b++) {
        bvh_tree t, plain;
        bvh_build_desc d = tu_scene_desc(&s, tu_builder(b));
        double sah_opt, sah_plain;
        tu_build_valid(&s, &d, &plain);
        d.optimize.rounds = 4;
        d.optimize.batch = 0.5f;
        d.threads = 1;
        tu_build_valid(&s, &d, &t);
        check_tree(&s, tris, boxes, &t, tu_builder(b));
        check_stats(&s, &t, tu_default_leaf(tu_builder(b)));
        same_on_threads(&s, d, &t, threads, sizeof threads / sizeof threads[0], "+opt");
        assert_int_equal(bvh_sah(&t, NULL, &sah_opt), BVH_SUCCESS);
        assert_int_equal(bvh_sah(&plain, NULL, &sah_plain), BVH_SUCCESS);
        if (id == TU_SCENE_BUNNY)
            print_message("%-18s %-14s SAH %.3f, optimized %.3f\n", s.name, bvh_builder_name(tu_builder(b)), sah_plain,
                          sah_opt);
        if (id == TU_SCENE_BUNNY &&
            (tu_builder(b) == BVH_BUILDER_PLOC_PARALLEL || tu_builder(b) == BVH_BUILDER_SAH_MIDPOINT) &&
            !(sah_opt < sah_plain))
            fail_msg("%s/%s+opt: SAH %g, not below the builder's %g", s.name, bvh_builder_name(tu_builder(b)), sah_opt,
                     sah_plain);
        bvh_free(&plain);
        bvh_free(&t);
    }
    free(boxes);
    free(tris);
    tu_scene_free(&s);
}

/* The optimizer's budget is its rounds: more rounds change the tree (on a scene with room to
   improve), and the tree of k rounds is the same whatever the batch's threads; a build from
   boxes takes it too. */
static void optimizer_rounds(void **state) {
    tu_scene s;
    bvh_tree t0, t1, t2;
    bvh_build_desc d;
    (void)state;
    tu_scene_random(&s, 3000, 0x6f707421ULL);
    d = tu_scene_desc(&s, BVH_BUILDER_PLOC_PARALLEL);
    tu_build_valid(&s, &d, &t0);
    d.optimize.rounds = 1;
    tu_build_valid(&s, &d, &t1);
    d.optimize.rounds = 6;
    tu_build_valid(&s, &d, &t2);
    assert_non_null(tree_diff(&t0, &t1));
    assert_non_null(tree_diff(&t1, &t2));
    bvh_free(&t0);
    bvh_free(&t1);
    bvh_free(&t2);
    tu_scene_free(&s);
}

int main(void) {
    const struct CMUnitTest tests[] = {
        TU_EVERY_SCENE(every_builder_valid),
        TU_EVERY_SCENE(builders_agree),
        TU_EVERY_SCENE(ploc_parallel_equals_ploc),
        cmocka_unit_test(ploc_parallel_equals_ploc_options),
        cmocka_unit_test(ploc_top_variants),
        cmocka_unit_test(memory_budget),
        cmocka_unit_test(leaf_sizes),
        cmocka_unit_test(options_build_valid),
        cmocka_unit_test(morton_sort_alone),
        TU_EVERY_SCENE(optimizer_valid),
        cmocka_unit_test(optimizer_rounds),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
