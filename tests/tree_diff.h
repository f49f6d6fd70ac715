/* tests/tree_diff.h - "the same tree" for every test that says so: every public array a build
   fills (binary nodes, references, triangles, the CPU traversal layout) and its count, byte for
   byte. Include after bvh.h. The one place to extend when a build fills another array. */
#ifndef TREE_DIFF_H
#define TREE_DIFF_H

#include <string.h>

#include "bvh.h"

/* NULL when a and b hold the same arrays, else the name of the first that differs. With
   structure_only, the binary nodes and references alone (a tree built from the triangles' boxes
   against one built from the triangles). */
static inline const char *tree_diff_ex(const bvh_tree *a, const bvh_tree *b, int structure_only) {
#define TREE_DIFF_ARRAY(field, count, size)                                                                            \
    do {                                                                                                               \
        if ((a->field == NULL) != (b->field == NULL)) return #field " (one is NULL)";                                  \
        if (a->field && (size_t)(count) && memcmp(a->field, b->field, (size_t)(count) * (size)) != 0) return #field;   \
    } while (0)
    if (a->node_count != b->node_count) return "node_count";
    if (a->ref_count != b->ref_count) return "ref_count";
    if (a->prim_count != b->prim_count || a->excluded != b->excluded) return "prim_count or excluded";
    TREE_DIFF_ARRAY(nodes, a->node_count, sizeof(bvh_node));
    TREE_DIFF_ARRAY(prims, a->ref_count, sizeof(uint32_t));
    if (structure_only) return NULL;
    if (a->node8_count != b->node8_count) return "node8_count";
    if (a->tri4_count != b->tri4_count) return "tri4_count";
    TREE_DIFF_ARRAY(tris, a->ref_count, 9 * sizeof(float));
    TREE_DIFF_ARRAY(nodes8, a->node8_count, sizeof(bvh_node8));
    TREE_DIFF_ARRAY(tri4, a->tri4_count, sizeof(bvh_tri4));
#undef TREE_DIFF_ARRAY
    return NULL;
}
static inline const char *tree_diff(const bvh_tree *a, const bvh_tree *b) { return tree_diff_ex(a, b, 0); }

#endif
