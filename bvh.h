/* bvh.h - v0.9.27 - MIT-licensed single-header BVH builder and ray tracer for C11/C++

   WHAT
     Builds bounding volume hierarchies over triangles (or any primitive given by its bounding box)
     and traces rays through them on the CPU. Five builders, from the study "Comparison of BVH
     construction methods" (Kedadry): baseline top-down (object median), baseline bottom-up
     (Morton-order pairwise aggregation), SAH-guided top-down with mid-point split partitioning,
     PLOC (Meister & Bittner 2018) and PLOC on pthreads. The node layout is a flat array of
     32-byte nodes that cl/trace.cl reads as-is on any OpenCL device; CPU tracing walks an 8-wide
     copy of it (bvh_node8, made by bvh_build unless desc.trace_width = 2). A tree follows moving
     primitives with bvh_refit (no allocation), and goes to bytes and back with bvh_save and
     bvh_load (through caller callbacks or a memory buffer; hostile input is refused).

   HOW TO INCLUDE
     In exactly ONE .c or .cpp file:
         #define BVH_IMPLEMENTATION
         #include "bvh.h"
     Everywhere else just #include "bvh.h". Link with -lm -lpthread.

   EXAMPLE
         float v[] = { 0,0,0,  1,0,0,  0,1,0,    0,0,1,  1,0,1,  0,1,1 };  // two triangles
         bvh_build_desc desc = {0};                   // zero = sensible defaults
         desc.builder = BVH_BUILDER_PLOC;             // or TOP_DOWN, BOTTOM_UP, SAH_MIDPOINT...
         desc.triangles.positions = v;                // stride 0 = tightly packed xyz floats
         desc.triangles.vertex_count = 6;
         desc.triangles.triangle_count = 2;           // indices NULL = 3 vertices per triangle
         bvh_tree tree;
         bvh_result r = bvh_build(&tree, &desc);
         if (r != BVH_SUCCESS) { printf("%s\n", bvh_result_string(r)); return 1; }
         bvh_ray ray = { {0.2f, 0.2f, -1}, 0.0f, {0, 0, 1}, BVH_INF };
         bvh_hit hit;
         if (bvh_intersect(&tree, &ray, &hit))
             printf("hit triangle %u at t=%g (u=%g v=%g)\n", hit.prim, hit.t, hit.u, hit.v);
         bvh_free(&tree);

   CONFIGURATION (define before including the implementation)
     BVH_MALLOC(size, user) / BVH_FREE(ptr, user)  default allocator (malloc/free); define both
                           or neither (one alone is a compile error); a per-build allocator with
                           a user pointer goes in bvh_build_desc.allocator (also both or neither)
     BVH_ASSERT(c)         internal consistency checks (default: assert from <assert.h>)
     BVH_STATIC            make every function static (private copy per translation unit)
     BVH_API               decoration of every public function (default extern, or static)
     BVH_NO_THREADS        no pthreads: parallel builders and batch tracing run on one thread,
                           or on the caller's own pool (bvh_thread_pool; see THREADS)
     BVH_NO_HUGEPAGES      on Linux with the default allocator, blocks of 4 MiB and more are
                           advised as transparent huge pages (madvise, in any C dialect on x86,
                           ARM64 and RISC-V; elsewhere it needs _DEFAULT_SOURCE or _GNU_SOURCE,
                           as gcc's default gnu dialects have); this turns that off
     BVH_MAX_DEPTH         traversal stack depth; builders never produce a deeper tree (64)
     BVH_NO_SIMD           no SSE intrinsics in 8-wide traversal and PLOC's neighbour search
                           (plain C, the same results); SSE is used where the compiler targets
                           it (x86-64 always)
     BVH_NO_AVX2           PLOC's neighbour search takes 8 pairs at a time, and traversal tests
                           8 boxes at a time, with AVX2 and FMA when the CPU has them (gcc/clang
                           on x86; compiled with a target attribute, no flag needed, the same
                           tree and hits); this keeps both to SSE

   ERRORS
     Every call that can fail returns a bvh_result; bvh_result_string() names it; the codes each
     call returns are listed beside its prototype. The library never aborts, exits or prints.
     NaN/Inf vertices (and boxes with min > max) are refused with a code, or left out and counted
     when desc.skip_invalid is set; indices out of range are always refused.

   THREADS
     No global mutable state: any function may be called from several threads on different trees.
     bvh_refit runs on desc.threads (two phases, each creating its threads once); bvh_load on
     bvh_load_desc.threads (a memory buffer's copy and checks, and the 8-wide packets).
     Parallel builders create their worker threads once per build phase (six per build, eight
     with the 8-wide copy, one more for PLOC's SAH top, one per extra collapse pass when PLOC's
     memory budget applies, one per round of the optimizer), never per iteration. At barriers
     they spin briefly before sleeping, unless the build has more threads than the machine has
     CPUs.
     Tracing only reads the tree (every call that takes a const bvh_tree *): any number of
     threads may trace one tree at once, batch calls included, while none builds into or frees it.
     Your own pool: desc.pool (and bvh_batch_desc.pool for the _ex batch calls, custom ones
     included, and the scene batch calls; bvh_scene_desc.pool, bvh_refit_desc.pool and
     bvh_load_desc.pool) is a parallel-for over the application's workers (a job system, TBB,
     OpenMP); with it the library creates no thread, splits each parallel phase into `threads`
     tasks and builds the very tree its own threads would. A task never waits for one that has not started, so phases
     whose threads meet at barriers are cut into one run per step (PLOC's clustering loop, the
     Morton sort, the emission passes; steps of under 4096 items run on the calling thread), and
     PLOC's SAH top is a task queue whose tasks wait only for running ones. On a platform
     without pthreads (MSVC without winpthreads, consoles, WebAssembly), define BVH_NO_THREADS
     and pass a pool with desc.threads (and the batch, scene, refit and load descriptions'
     threads) set to its worker count: parallel builds, batches, refits and loads with no
     pthread anywhere (see bvh_thread_pool). A batch call on a pool runs `threads` tasks that
     take chunks of rays from a shared counter; an application without a job system can start a
     pool once with examples/workers.h.

   PROGRESS AND CANCEL
     desc.progress(user, fraction) is called on the thread that called bvh_build, one call at a
     time: once at the start, between the build's stages and the steps of its parallel phases,
     and every 65536 primitives in the serial builders' loops; fractions rise to a single 1 when
     the build completes. A nonzero return cancels: bvh_build returns BVH_ERROR_CANCELLED soon
     after (the tree empty, nothing leaked); the return of the call at 1 is ignored.

   MEMORY AND STACK
     bvh_build keeps no pointer to the caller's buffers: the tree holds its own copy of the
     triangles (tree.tris, 36 bytes per reference, and tree.tri4), so vertices, indices and boxes
     may be freed when it returns; only desc.allocator (functions and user pointer) must stay
     valid until bvh_free. A tree holds 32 bytes per node, 4 per reference, 36 per reference of
     triangles and, with the 8-wide copy, 256 per bvh_node8 and 160 per bvh_tri4: about 110
     bytes per triangle for a default build of a scanned mesh, 58 with trace_width = 2
     (bvh_get_stats gives a tree's own figures). Stack: nothing grows with the input (explicit
     stacks sized by BVH_MAX_DEPTH; the one recursion, the Morton sort's, is at most 15 deep).
     bvh_intersect and bvh_occluded take under 8 KiB optimised (the 8-wide stack is 12 bytes
     times 7 * BVH_MAX_DEPTH + 8; 17 KiB at -O0), about 1 KiB with trace_width = 2; the batch
     calls under 20 KiB a thread (two rays in turns: 40 KiB at -O0); bvh_build
     under 63 KiB (gcc's frames, -O0 to -O3) plus malloc's, on the calling thread and on each
     worker (created with the default pthread stack size).

   LICENSE
     MIT, see the end of this file.

   CHANGELOG
     0.9.27 Builds on a caller's pool (desc.pool) run every phase on its tasks: the Morton sort,
            the emission passes and PLOC's SAH top ran on the calling thread there (their
            threads met at barriers), and a default build on two workers took 1.27-1.33x the
            library's own threads' time; now 1.05-1.06x (the bunny, Sponza, the dragon). The
            sort and the passes are cut at their barriers into runs as PLOC's loop is; the top's
            queue needs none (its tasks wait only for running ones). The same trees.
            bvh_refit_desc.pool, bvh_load_desc.pool and bvh_scene_desc.pool: refits, loads and
            a scene's top level on a caller's pool too (they started the library's threads every
            call: a refit or a scene rebuilt every frame, say), the same bytes as its threads give.
            bvh_intersect_custom_batch_ex and bvh_occluded_custom_batch_ex: the custom
            primitives' batches with a bvh_batch_desc (threads, pool), on the tree batches'
            runner (they had a runner of their own).
            A refit's check that every vertex is finite takes 32 floats a step with AVX2 (16 with
            SSE2): refits 2-3.5% faster (the dragon, gen:field:15; both trees).
     0.9.26 The batch calls on a caller's pool (bvh_batch_desc.pool, the scenes' batches) run
            `threads` tasks that each take guided chunks as the library's threads do, with a
            tuning of their own, where each 64-ray chunk was a task: a persistent pool (the new
            examples/workers.h) traced a frame's bounce and shadow rays 0.74-0.82x as fast as
            the library's own threads on Sponza and 0.91-0.92x on the bunny; now 1.02-1.09x and
            1.00-1.02x (2 threads). So bvh_batch_desc.threads now counts under a pool too (it
            was ignored there): with BVH_NO_THREADS set it to the pool's worker count.
     0.9.25 A camera's closest-hit batches (rays from one origin) on layouts from 512 KiB are timed
            too, where they always went one ray at a time: from inside a model or a room every
            ray goes deep and two in turns run up to 1.37x as fast (camera rays from inside, one
            thread, against Embree medium: the dragon 0.92 -> 1.25-1.28, Sponza 0.89-0.93 ->
            1.01-1.02, gen:field:15 0.78-0.93 -> 0.84-0.98); seen from outside the samples keep
            them one at a time, as fast as before.
     0.9.24 A timed batch (0.9.21) decides from samples whose halves are neighbouring rays, one
            half in turns and one alone, and from the median of their ratios: it traced the same
            rays both ways, and in a renderer's cold caches the second pass ran up to twice as fast
            as the first, so that a third of the bunny's one-thread bounce batches went the slower
            way (now 1 in 66, and 1 in 66 inside Sponza the other way); every ray is now traced
            once. The allocator is called only on the calling thread (tested), so a block cache for
            rebuilds every frame needs no lock (docs/GUIDE.md).
     0.9.23 The batch calls' threads take guided chunks, each a quarter of a thread's share of the
            rays left (at least 64), where they took chunks of 1,024 rays in turn: a thread walks
            long stretches of neighbouring rays, whose nodes its core's caches then hold. Two
            threads over one on camera rays 1.92-2.03 (0.9.22: 1.62-1.92), the bunny's two-thread
            camera rays 12% faster. A timed batch (0.9.21) spreads its samples over its first
            range.
     0.9.22 The batch calls' one-ray closest-hit loop asks for the lines of the ray and the hit 32
            places ahead: camera rays (25-40 ns each) had outrun the cores' own prefetchers, so
            that a range's length moved them by up to 17%. Camera rays 1.04-1.21x as fast on one
            thread, 1.04-1.11x on two; on one thread too a batch is now cut into ranges of 1,024
            rays (was 64), so that the look-ahead runs on. Bounce and shadow rays level.
     0.9.21 On an 8-wide layout between 512 KiB and 16 MiB, a batch of a renderer's closest-hit
            rays of 16,384 or more a thread times its first ranges both ways, one ray at a time
            and two in turns (eight samples of 64 rays, each traced twice), and traces the rest
            the faster way: an object's bounce rays go in turns (the bunny 9-11% faster), a
            room's stay one at a time (Sponza from inside, which turns slowed 3-5%). The same hits
            either way. A closest-hit push asks for its child's lines by an address made of masks
            (gcc had turned the select into a branch, mispredicted on long rays): bounce rays in
            turns 1-5% faster.
     0.9.20 The batch calls trace two rays in turns (rays from different origins: a renderer's
            bounce and shadow rays; closest hit on an 8-wide layout of 16 MiB or more, any hit
            from 512 KiB), a step of one and a step of the other, so that one ray's wait for its
            nodes overlaps the other's work: bounce rays 9-19% faster on the dragon and
            gen:field:15, shadow rays 5-16% there and up to 33% on smaller trees (one thread),
            the same hits. Camera rays (one origin) keep the one-ray loop.
     0.9.19 PLOC's collapse (the default builder) prices an interior node at 2.5 triangle tests
            (was 1.2): subtrees of a few triangles become leaves, which the 8-wide layout tests
            as one packet anyway. The binary tree has 44-46% fewer nodes (the dragon 903,487 ->
            504,557; 37.2 -> 22.5 bytes a triangle), the default tree with its layouts takes
            107.7 bytes a triangle on the bunny (was 122.8), SAH is 3-6% higher, and the 8-wide
            trace speed is the same within noise (0.99-1.03x on camera, bounce and shadow rays,
            one thread). The layout costs 6-13% of the build (was 10-17%); refit and load of
            these trees take 0.73-0.87x the time. Loads read the nodes once (a borrowed load
            hashes them in the structure check), and the 8-wide pass checks the child boxes
            where it reads them.
     0.9.18 bvh_load_desc.borrow: a memory buffer's binary nodes, references and triangles become
            the tree's arrays, read in place (tree.borrowed; same checks; the buffer is never
            written, bvh_free leaves it, bvh_refit refuses the tree): a cache file read or mapped
            whole loads without copying 60-75 bytes a triangle. Loads, borrowed or not, are
            faster: a wide node's leaf triangles are asked for before they are checked, and each
            thread first touches its own fresh pages (the threads faulted on the same huge pages
            and waited on each other). Against 0.9.17 in one process (21 rounds, 2 threads): a
            copying load 0.85x on gen:field:15 (both trees), the dragon 0.84x (bottom-up tree),
            0.99x (ploc-parallel); same trees. bvhbench: gen:field:15's bottom-up tree loads in
            29-34 ms copying, 25-29 borrowed, against 153-157 ms for its build.
     0.9.17 bvh_refit in three quarters of the time, the same tree bit for bit: a leaf slot's
            triangles are gathered into the thread's scratch and its boxes and packets made from
            there; the packets and tree.tris are then streamed past the caches (non-temporal
            stores: a store that missed read its line from memory first), and a packet's
            zero-area check is decided in float where it can be (a bound on the float error
            shows the double test would find the area nonzero; the double test otherwise). The
            triangles of the references after a wide node's are asked for ahead. In one process
            against 0.9.16 (15 rounds, 2 threads): gen:field:15 0.76x (bottom-up tree) and 0.83x
            (ploc-parallel), the dragon 0.77x and 0.92x; builds and loads, which write their
            packets the same way, level. Refit scratch 9 -> 20 KiB of stack a thread.
     0.9.16 The 8-wide layout in half the time, the same layout bit for bit: the least-cost cut's
            dynamic program walks up to 64 binary subtrees on the build's threads in post-order,
            its rows on the walk's stack (was: one thread over the whole tree, a table of 32 bytes
            a node), and keeps 16 bytes a node with the cut's choices, which the passes that count
            and write the wide nodes replay (was: searched again in both); the triangles of a
            wide node's leaf slots are asked for ahead; the write pass takes its subtrees most
            packets first; a node that may not be opened skips the dynamic program. bvhbench
            --layout-cost (new: each timed build paired with one without the layout),
            ploc-parallel on two threads, four runs: the layout adds 14-17% to the bunny's build
            (was 27-31%), Sponza's 11-16% (22-25%), the dragon's 11-17% (32-38%), gen:field:15's
            16-20% (37-40%). Its scratch memory 40 -> 16 bytes a binary node, which was the
            build's peak: bvhbench's counting allocator, bytes a triangle, ploc and
            ploc-parallel 153-166 -> 141, bottom-up 121 -> 109, top-down 121-138 -> 120-124.
     0.9.15 A wide node's interior slots are stored, and taken by any-hit rays, by the chance that
            their subtree stops a ray for what it costs that ray (the triangles' area over half
            the box's, capped at 1, over the layout's expected cost; Ize & Hansen's shadow-ray
            order), after the leaf slots (was: largest box first). In-process A/B on an Intel
            Xeon, shadow rays: Sponza from inside +34% on the sah-midpoint tree (0.81 -> 1.09x
            Embree medium), -4% on the ploc-parallel one; the dragon +2% and +5%; the bunny,
            gen:field:15 and Sponza from outside within 2%. Closest-hit rays sort by distance
            and break ties by slot: Sponza's camera rays from outside -5% on the ploc-parallel
            tree, the rest within 2%. The path tracer (Sponza inside, three bunnies, one thread)
            0.99-1.00x -> 1.01-1.02x Embree. The build sums the triangles' areas in the layout's
            cost pass: +5 ms a million triangles (docs/bench).
     0.9.14 Transparent huge pages for the default allocator's big blocks in an ISO-only dialect
            too (-std=c11 with no feature macro hides madvise: bvh.h declares it on x86, ARM64
            and RISC-V). Such a build was losing the advice: gen:field:15's ploc-parallel
            build 270 -> 225-239 ms, bvh_load 0.82x the time (the dragon's 0.92-1.00x), refit
            0.95-0.98x, large scenes' tracing +1-3% (docs/bench).
     0.9.13 A scene hit's world normal is compiled into each ISA's scene function (was: a call
            from the AVX2 one to base-ISA code; the same bits): one identity instance against
            the tree, bvhbench's paired rounds, three runs each, the bunny 0.86-0.87x ->
            0.88x, gen:field:15 0.89x -> 0.90x, the dragon 0.90-0.95x -> 0.91-0.92x
            (docs/bench).
     0.9.12 The closest-hit batch calls trace a range of rays in one call on the AVX2 path (was:
            a call a ray). In-process A/B on a Zen 3: camera rays +2-4%, Sponza's bounce rays
            +6-16%, the bunny's and the dragon's level (docs/bench).
     0.9.11 On AMD's cores the fast AVX2 slab test takes its max and min as float operations
            (one cycle there, and no crossing to the integer unit); Intel's keep the integer
            ones of 0.8.5. On a Zen 3 against Embree medium (its AVX2 kernels), in-process
            paired passes: the bunny's and Sponza's bounce and shadow rays +2-5%, the dragon's
            +1-4% on the sah-midpoint tree, level on the ploc-parallel one (docs/bench).
     0.9.10 A wide node's slots are stored leaf slots first, then by area (was: by area alone),
            the order any-hit rays take them: fewer nodes before a blocker is found. Shadow rays
            against Embree medium, two bvhbench runs each: Sponza from inside 0.91-0.92 ->
            0.93-0.94x (ploc-parallel), 0.77-0.78 -> 0.81-0.82x (sah-midpoint), from outside +2%;
            the bunny, the dragon and gen:field:15 level (docs/bench).
     0.9.9  The 8-wide layout takes each wide node's slots as the cut of least expected cost (a
            dynamic program over the binary tree, Ylitie, Karras & Laine 2017) instead of
            opening the largest box first; a leaf slot is cut only into as many packets. The
            same binary tree, packets and hits; fewer, fuller wide nodes. Against Embree medium
            (two bvhbench runs): Sponza from inside, ploc-parallel camera 0.82-0.88 -> 0.94-0.95x,
            shadow 0.79-0.87 -> 0.91-0.92x; the bunny's bounces 0.91 -> 0.93x; sah-midpoint's
            shadow rays inside Sponza stay at 0.78x (docs/bench). The build keeps a table of 32
            bytes a binary node while it makes the layout (1M triangles: peak +21 MB) and spends
            about 11 ms more a million nodes.
     0.9.8  bvh_refit's 8-wide walk takes a wide node's children in the order of their binary
            nodes (bvh_node8.order read back; the slots are stored largest box first), so it
            reads the references, the caller's triangles and the binary nodes nearly in order:
            a refit of gen:field:15 or the dragon on two threads 19-22 -> 18-22 ms and 20-22 ->
            18-19 ms (three alternated bvhbench runs each, docs/bench). The same boxes.
     0.9.7  The fast slab test takes tmin as a fourth operand of its integer max (no deeper),
            so one compare decides a slot instead of two and an and: the same decisions and
            entry distances. A scene's top level takes slot 0 without waiting for the mask's
            index when it is the only slot entered (a predicted branch instead of a data
            dependency before the instance's set-up). Bunny: 1,100 -> 1,089 instructions a
            bounce ray, 942 -> 937 a shadow ray; one thread against Embree medium, four runs
            each: bunny bounce / shadow +1-2%, the rest level (docs/bench).
     0.9.6  The triangle tests (bvh__tri_test, both packet tests, trace.cl) miss a triangle with
            edge functions of both signs before they look for a zero one (a float edge
            function's sign is exact where it is not zero): the zero check and the double
            fallback only for the triangles left, the same hits. Any-hit traversal keeps no
            entry distances (its loop ends at the first hit) and the push chooses its prefetch
            address by a conditional move. Bunny, ploc-parallel tree: 1,131 -> 1,100
            instructions a bounce ray, 1,015 -> 942 a shadow ray; one thread against Embree
            medium: dragon bounce +1%, shadow +2%, bunny shadow +1%, bounce level (docs/bench).
            bvh_load allocated a byte per primitive for its checks, which a file of a build
            that left most primitives out (skip_invalid) does not bound: 1.5 MB for a 100-byte
            file (fuzz_load). Where primitives far outnumber references, it now counts them in
            a sorted copy of the references.
     0.9.5  The AVX2 loop's slab test, for rays with tmin >= 0 and no zero direction component,
            takes its slack once a ray and tree (1.25 * 2^-18 of the farthest distance along
            the dominant axis from the origin to the root box's planes, taken off each entry in
            a fused multiply-subtract) and its exit factor in the reciprocal, so that neither is
            on the chain from a node's boxes to its mask. It enters every box the exact test
            enters, at the same or a nearer distance: the same hits. The AVX2 paths now also
            need FMA (every AVX2 processor has it). One thread against Embree medium, bounce /
            shadow rays: bunny 0.86-0.93 / 0.81-0.86 -> 0.88-0.97 / 0.86-0.90, dragon
            0.88-1.03 / 0.86-0.94 -> 0.93-1.02 / 0.89-0.96, Sponza from inside +3-8%, the path
            tracer 0.88x -> 0.93-0.94x; rays that leave the scene after a node or two pay for
            the set-up (Sponza from outside 0-8% slower, still 1.3-1.6x Embree) (docs/bench,
            0.9.5).
     0.9.4  A wide node's slots are stored largest box first, and any-hit rays take a node's
            entered slots in that order (they took them lowest slot first, then the rest from
            the last): a larger box is likelier to hold what blocks a shadow ray. bvh_node8
            gains order[8] in its padding (where each slot of the grouping went), which
            bvh_refit and bvh_load follow; saved files of 0.9.2-0.9.3 (order all zero) still
            load. Sponza from inside, sah-midpoint tree: shadow rays 0.68x -> 0.80x Embree;
            the path tracer 0.82-0.86x -> 0.88-0.95x (docs/bench, 0.9.4).
     0.9.3  A scene ray is one function per ISA and kind from the checks to the hit record, and
            the world normal is computed in scalars (the same bits): one identity instance
            against the tree 0.79-0.86x -> 0.82-0.89x its speed (docs/bench, 0.9.3).
     0.9.2  The tree optimizer (desc.optimize) does the same work in less time: candidates that
            nearly fill their parent's box are not searched (BVH__OPT_FILL: other trees, about
            the same SAH), each round's candidates come from subsets sorted once, a refit stops
            at the first box that does not change, the search asks for a node's children as
            soon as it reads the node and the apply for a move's slots eight moves ahead
            (docs/bench, 0.9.2).
     0.9.1  bvh_refit and bvh_load ask ahead for the binary nodes their 8-wide walk is about to
            follow (bvh__refit_ask: the next wide nodes' heads and their descendants' block):
            the same trees; refit 10-20% faster (the dragon and gen:field:15, one and two
            threads), load 0-15%.
     0.9.0  bvh_scene_intersect_batch and bvh_scene_occluded_batch: a scene's rays in arrays, one
            mask per call (as bvh_cl_scene_intersect), on desc's threads or pool (bvh_batch_desc,
            as bvh_intersect_batch_ex), with the single-ray calls' hit records byte for byte.
            The tree and scene batches share one chunked runner (bvh__batch_go).
     0.8.7  The batch calls ask for the CPU's ISA once a range of rays, not once a ray, and the
            ray set-up compares the direction with zero once: bvhbench's traced sets on the
            bunny (one thread, callgrind) 82.4M -> 81.9M instructions, the same hits.
     0.8.6  The slab test never takes a box's entry below tmin (it lowered the entry by a slack
            for rounding, 2^-18 of the box's extent along the ray's dominant axis, even where
            that went below tmin): a box whose exit, rounded up, is before tmin holds no hit
            and is no longer entered, however near the origin it lies. The hit's own box check
            (bvh__tri_reach, all its SIMD forms) and cl/trace.cl say the same, so the hits stay
            the brute-force ones. Such boxes were entered by every ray of an eye lying within
            the slack of a plane of box faces: Sponza seen from inside along its centre line
            (bvhbench --camera inside), camera rays 13.7 -> 11.9 nodes and 3.5 -> 1.8 leaves a
            ray (ploc-parallel). Paired against Embree there, five alternated runs: camera rays
            0.63 -> 0.73-0.76 (ploc-parallel), 0.56-0.59 -> 0.70-0.72 (sah-midpoint); bounce
            rays flat, shadow rays -1%; outside the bunny, shadow rays -2% to -4%.
     0.8.5  The AVX2 slab test takes max and min of the distances as integers (one cycle each
            on the chain from a node's boxes to its mask, four as floats) for rays with tmin
            >= 0 and no direction component zero, in a second copy of the loop chosen once a
            ray; the same entry distances, and never a box culled that the float test enters
            (other rays: the float test as before). Three alternated bvhbench runs against
            0.8.4, bounce and shadow rays, a run and tree: bunny -2% to +13% (median +4%),
            dragon -4% to +15% (median +7%).
     0.8.4  The batch calls (bvh_intersect_batch, bvh_occluded_batch and their _ex forms) take
            each ray straight to the 8-wide loop, as bvh_intersect does (were: through the
            entry that also holds the binary-tree path, whose checks and stack frame cost a
            camera ray that misses about as much as its set-up): bunny camera rays through
            bvh_intersect_batch, 366 -> 313 instructions a ray.
     0.8.3  The AVX2 packet test reads the ray's broadcast operands and row offsets from a block
            made once per ray at its first leaf (was: set up in registers at every leaf and
            spilled): bunny, instructions per ray 1,167 -> 1,114 (bounce), 1,093 -> 1,013
            (shadow), the same decisions. bvhbench --paired also times Embree high in the same
            rounds (ratio_build_high_paired) and each tracing pass on --threads right after its
            one-thread pass (the paired thread scaling, scaling_mt_paired).
     0.8.2  Batches hand out chunks of 1,024 rays, then 64 at the end (were 64): two threads
            on the bunny's camera rays 1.46-1.59x -> 1.80-1.93x one thread. A lighter ray
            set-up for the 8-wide loop (same decisions): bunny camera rays 0.89x -> 1.03x
            Embree (median of three alternated runs). bvh_validate and bvh_load refuse leaves
            whose reference ranges overlap (a fuzzed file with split references got through).
            bvh_scene_intersect writes its hit record once. examples/pathtrace.c puts its
            spheres in the CPU's scene as a custom instance (was a second traversal per ray):
            0.73x -> 0.81x Embree on its own rays, one thread.
     0.8.1  The 8-wide slab tests (AVX2 and SSE) take the same operations regrouped into trees,
            so that the chain from a node's boxes to the next node's address is shorter (same
            decisions; only the order of children at exactly equal distances can change):
            bunny, paired against Embree 3 medium with its default flags, +0-13% a ray kind.
            bvhbench measures Embree with its default scene flags unless --embree-flags robust
            (its earlier figures were all against the robust flag, which slows Embree by
            1.3-1.5x on bounce and shadow rays).
     0.8.0  Scenes: the CPU traces a scene's top level through an 8-wide copy of it
            (bvh_scene.top8, one instance a leaf slot with its own world box) with the 8-wide
            loop and a leaf step, not the binary walk with scalar tests; bvh_scene.own_box is
            gone (every slot is an instance's own box). An instance whose transform is exactly
            the identity is traced on the world ray's set-up (no transform, no second set-up).
            The instance step calls the bottom level's loop for the same ISA directly. The AVX2
            loop sets up the ray's three axes in vector registers, orders three or more entered
            children by rank (no loop on the distances) and picks the packets' box planes by a
            blend: fewer mispredicted branches. The AVX2 paths now also require POPCNT (every
            AVX2 CPU has it). A path tracer's rays inside Sponza with three bunnies: 2,613 ->
            2,134 instructions a ray (callgrind; Embree 3: 1,658).
            bvh_load: the ordered checks of the binary tree (one forward pass) run on one thread
            while the load's team remakes the 8-wide layout, whose steps check every index they
            follow and which checks each leaf's triangles against its box as it reads them for
            the packets (no pass of its own over tree.tris); without the 8-wide layout the
            leaves' triangles are checked on the team. From a memory buffer the 8-wide nodes are
            read straight into their block (the packets counted in the buffer first), not
            through a copy. The format is unchanged (version 2). bvh_refit's 8-wide pass hands
            its subtrees to whichever thread is free. A packet's zero-area test runs in SSE2 on
            the transposed coordinates (byte-identical packets). On a shared, busy 2-core VM
            (docs/bench/README.md, medians of three alternated runs): load of the dragon 87 ->
            46 ms (bottom-up tree), 130 -> 99 (ploc-parallel), 177 -> 85 (sah-midpoint); of
            gen:field:15 58 -> 65, 143 -> 97, 108 -> 99; rebuild / load 1.3-3.1x, rebuild /
            refit 2.8-6.7x (refit unchanged within the noise): issue #17's 5x and 10x are not
            met, both bound by memory bandwidth and first-touch page faults.
     0.7.0  CPU tracing: the 8-wide layout fills free slots (leaf slots are opened into their
            children where the packet tests' expected cost falls and no packet is added: the
            same memory, different tree.nodes8 and tree.tri4 contents, the same hits); closest
            and any hit run as separate functions with fewer mispredicted branches per ray; a
            scene hit takes its normal's vertices from the packet just tested; a top-level leaf
            tests each instance's own world box (bvh_scene.boxes, kept from the build) before
            the ray is transformed.
            Instances of custom primitives: bvh_instance.custom (a bvh_custom_desc) traces an
            instance of a tree built from boxes with the caller's test in the instance's space,
            or decides for each triangle of a triangle tree (alpha testing); such hits' normal is
            zero for box trees. bvh_cl_scene_upload refuses instances with a callback. A
            positional initializer of bvh_instance needs the new last field (NULL); designated
            and zero initializers are unchanged.
            bvh_refit updates the 8-wide layout in one pass over it (boxes and packets in place,
            from each wide node's grouping: bvh_node8 gains head and shape in its padding, pad is
            now 4 words) instead of replaying the build's grouping; the tree no longer keeps a
            byte per binary node for it. Save format version 2 stores the 8-wide nodes; bvh_load
            remakes only their packets and boxes (checked against the binary tree, on
            bvh_load_desc.threads) and checks the binary tree in linear passes; the payload
            checksum is per 256 KiB piece. Version 1 files are refused
            (BVH_ERROR_UNSUPPORTED_FORMAT): build and save again.
            sah-midpoint builds on the build's threads (desc.threads or the caller's pool;
            bvh_builder_info.uses_threads is now 1 for it), the same tree byte for byte for any
            thread count and as before on one thread.
            The tree optimizer: bvh_build_desc.optimize (bvh_optimize_options: rounds, 0 = off,
            the default; batch, 0 = 0.1) runs rounds of parallel reinsertion (Bittner et al.
            2013, Meister & Bittner 2018) on any builder's binary tree before the collapse to
            leaves, on desc.threads or desc.pool, the same tree for any thread count; rounds
            above 1024 and a batch outside [2^-16, 1] are refused.
            cl/bvh_cl.h 0.4.0: two-level scenes on OpenCL. bvh_cl_scene_upload copies a
            bvh_scene (top-level tree, instances, each distinct bottom-level tree once) to the
            device, bvh_cl_scene_free releases it; bvh_cl_scene_intersect / bvh_cl_scene_occluded
            trace batches with one mask per call and give bvh_scene_intersect's bvh_scene_hit, to
            the bit on an exact device. trace.cl's one traversal loop gained a level switch.
            Tools: bvhbench's "build 1t" column and `<builder>+opt` rows; examples/pathtrace.c
            --trace opencl|auto (the CPU's image byte for byte), --embree (the same scene on
            Embree 3: instances and a user geometry), --add MODEL, --json.
     0.6.0  The public surface made regular. Builder-specific options moved into nested structs,
            zero still the default (the same trees): desc.ploc_radius -> desc.ploc.radius,
            desc.ploc_top -> desc.ploc.top, desc.max_bytes_per_prim ->
            desc.ploc.max_bytes_per_prim, desc.sah_bins -> desc.sah_midpoint.bins,
            desc.split_budget -> desc.sah_midpoint.split_budget. One spelling of "off", BVH_OFF,
            replaces BVH_PLOC_TOP_OFF, BVH_NO_MEMORY_LIMIT and BVH_SAH_MIDPOINT_ONLY, and a
            negative split budget (now refused; BVH_OFF = no splits). bvh_builder_info gives the
            defaults of both (info.ploc, info.sah_midpoint). Defining only one of BVH_MALLOC and
            BVH_FREE is a compile error; bvh_validate and the batch calls refuse a tree with a half
            allocator pair as bvh_build refuses such a desc. bvh_validate refuses a child stored
            before its parent. Each call's result codes are listed beside its prototype.
            cl/bvh_cl.h 0.3.0: bvh_cl_desc.allocator (a bvh_allocator), BVH_CL_MALLOC/BVH_CL_FREE
            take the user pointer; it holds the kernel (no cl/trace.cl needed at run time;
            BVH_CL_KERNEL_PATH and desc.kernel_path, when set, still read a file). The 8-wide
            traversal runs fewer instructions per ray (the same hits).
            Your own thread pool: bvh_thread_pool in bvh_build_desc.pool and in
            bvh_batch_desc (bvh_intersect_batch_ex, bvh_occluded_batch_ex), the same trees and hits
            as the library's threads; with BVH_NO_THREADS, parallel builds without pthreads.
            Progress and cancel: bvh_build_desc.progress / progress_user, BVH_ERROR_CANCELLED.
            Custom primitives: bvh_intersect_custom, bvh_occluded_custom and their batch calls
            trace a tree built from boxes with the caller's intersection callback (bvh_custom_desc;
            ties to the lowest index; a t outside [tmin, tmax] or NaN is ignored). Instances:
            bvh_scene_build / bvh_scene_intersect / bvh_scene_occluded over bottom-level triangle
            trees placed by 3x4 transforms, with ids and ray masks (bvh_instance, bvh_scene_hit
            with the world normal), bvh_ray_transform. Secondary rays: bvh_offset_origin
            (Waechter & Binder 2019) and bvh_hit_surface (hit point and geometric normal).
            bvh_refit (moved vertices or boxes; binary boxes, tree.tris and the 8-wide layout in
            place, the build's grouping kept; parallel; allocates nothing), bvh_save/bvh_load (a
            versioned, checksummed format through callbacks or memory; the 8-wide layout is
            remade on load; truncated, damaged and hostile input refused with BVH_ERROR_TRUNCATED,
            BVH_ERROR_CORRUPT, BVH_ERROR_UNSUPPORTED_FORMAT; BVH_ERROR_IO for a failed write).
            The nodes8 block also holds a byte per binary node: the grouping refit replays.
     0.5.0  CPU tracing walks an 8-wide copy (bvh_node8, tree.nodes8; AVX2 slab test when the
            CPU has it) whose leaves are SIMD packets of four triangles (bvh_tri4, tree.tri4);
            the watertight triangle test is done in float with a double fallback where an
            edge function is zero (hits, t, u and v change in the last bits); trace_width 8.
            The builder table (bvh_builder_get_info) and one option resolver. The implementation
            keeps IEEE semantics under -ffast-math (gcc; clang: #error without
            -fno-finite-math-only). Vertices at any alignment; misaligned indices and
            allocators, and half allocator pairs, are refused. bvh_sah and bvh_get_stats refuse
            broken trees; box trees miss in the batch calls too. The CPU layout's numbering no
            longer depends on the thread count. Removed: desc.keep_triangles (never read).
     0.4.1  PLOC builds ask ahead for the boxes gathered into Morton order and for the nodes
            that root-down emission writes (same trees, a few % faster).
     0.4.0  PLOC's memory budget (desc.max_bytes_per_prim, 40 by default; BVH_NO_MEMORY_LIMIT):
            where the SAH collapse leaves a tree over it (random triangle soups), leaves grow
            until it fits. Smaller neighbour-search buffers on inputs under 1024 primitives.
            CPU traversal makes the triangle test's shear only when a ray reaches a leaf.
     0.3.0  PLOC's SAH top (desc.ploc_top, on by default; BVH_PLOC_TOP_OFF for the paper's PLOC):
            a binned-SAH top over PLOC's last n / 8 clusters, kept where it is cheaper.
     0.2.1  faster PLOC builds, same trees: AVX2 neighbour search, root-down emission, MSD Morton
            sort, fewer stalls in the front end (BVH_NO_AVX2 to keep SSE).
     0.2.0  4-wide copy of the tree for CPU traversal (bvh_node4, tree.nodes4, trace_width),
            checked by bvh_validate.
     0.1.0  first release: types, SAH evaluator, validator, CPU traversal, baseline builders.
*/
#ifndef BVH_H_INCLUDED
#define BVH_H_INCLUDED

#define BVH_VERSION_MAJOR 0
#define BVH_VERSION_MINOR 9
#define BVH_VERSION_PATCH 27

#include <math.h>
#include <stddef.h>
#include <stdint.h>

#ifndef BVH_API
#if defined(BVH_STATIC) && (defined(__GNUC__) || defined(__clang__))
#define BVH_API static __attribute__((unused))
#elif defined(BVH_STATIC)
#define BVH_API static
#else
#define BVH_API extern
#endif
#endif

#ifndef BVH_MAX_DEPTH
#define BVH_MAX_DEPTH 64
#endif
#if BVH_MAX_DEPTH < 64
#error "BVH_MAX_DEPTH must be at least 64: depth-bounding rebuilds need 32 levels below depth 31"
#endif

#define BVH_INF HUGE_VALF
#define BVH_INVALID 0xFFFFFFFFu
/* Turns off a build option that can be switched off (desc.ploc.top, desc.ploc.max_bytes_per_prim,
   desc.sah_midpoint.bins, desc.sah_midpoint.split_budget): one spelling for every such option,
   integer or float. 2^31 is exact as a float, and as a number it would mean "never" in every
   integer option that takes it. */
#define BVH_OFF 0x80000000u

#ifdef __cplusplus
extern "C" {
#endif

/* ---- results ------------------------------------------------------------------------------ */
typedef enum bvh_result {
    BVH_SUCCESS = 0,
    BVH_ERROR_INVALID_ARGUMENT,    /* NULL pointer, option out of range, stride < 12 ... */
    BVH_ERROR_INVALID_GEOMETRY,    /* NaN or Inf in a vertex or box (see skip_invalid) */
    BVH_ERROR_INDEX_OUT_OF_RANGE,  /* a triangle index >= vertex_count */
    BVH_ERROR_TOO_MANY_PRIMITIVES, /* count does not fit the 32-bit reference budget */
    BVH_ERROR_OUT_OF_MEMORY,       /* an allocation failed; nothing leaked, tree left empty */
    BVH_ERROR_THREAD,              /* reserved, never returned: a build or batch whose worker
                                      threads cannot all be created runs on those it has */
    BVH_ERROR_INVALID_TREE,        /* the validator found a defect (see bvh_validation) */
    BVH_ERROR_NO_TRIANGLES,        /* traversal asked of a tree built from boxes only */
    BVH_ERROR_CANCELLED,           /* the build's progress callback asked to stop; nothing
                                      leaked, tree left empty */
    BVH_ERROR_IO,                  /* bvh_save: the write callback took fewer bytes than given */
    BVH_ERROR_TRUNCATED,           /* bvh_load: the data ends before the tree does */
    BVH_ERROR_CORRUPT,             /* bvh_load: not a saved tree, or damaged (magic, checksums,
                                      sizes out of range, a tree that fails validation) */
    BVH_ERROR_UNSUPPORTED_FORMAT,  /* bvh_load: a format version this library does not read, or
                                      a file saved on a machine of the other byte order */
    BVH_RESULT_COUNT
} bvh_result;

/* ---- builders ----------------------------------------------------------------------------- */
typedef enum bvh_builder {
    BVH_BUILDER_DEFAULT = 0,   /* = BVH_BUILDER_PLOC_PARALLEL */
    BVH_BUILDER_TOP_DOWN,      /* "top-down": object median on the longest centroid axis */
    BVH_BUILDER_BOTTOM_UP,     /* "bottom-up": Morton order, pairwise aggregation per level */
    BVH_BUILDER_SAH_MIDPOINT,  /* "sah-midpoint": SAH-guided mid-point split partitioning */
    BVH_BUILDER_PLOC,          /* "ploc": Meister & Bittner 2018, one thread */
    BVH_BUILDER_PLOC_PARALLEL, /* "ploc-parallel": the same tree, built on a pthread pool */
    BVH_BUILDER_COUNT
} bvh_builder;

/* ---- math types --------------------------------------------------------------------------- */
typedef struct bvh_vec3 {
    float x, y, z;
} bvh_vec3;
typedef struct bvh_aabb {
    bvh_vec3 min, max;
} bvh_aabb; /* empty: min = +inf, max = -inf */

/* A node: 32 bytes. count == 0: interior node whose children are nodes[index] and
   nodes[index + 1]. count > 0: leaf referencing tree.prims[index .. index + count - 1].
   The root is nodes[0]. cl/trace.cl reads this array as-is.
   Invariant of every builder's output: children are stored after their parent (index > the
   parent's own position), so one forward pass meets every parent before its children and no
   index can form a cycle; bvh_validate refuses a tree that breaks it. */
typedef struct bvh_node {
    bvh_vec3 min;
    uint32_t index;
    bvh_vec3 max;
    uint32_t count;
} bvh_node;

/* An 8-wide node (256 bytes, four cache lines) of the layout CPU traversal uses
   (bvh_tree.nodes8): the boxes of up to eight children by axis, so that one SIMD slab test (two
   with SSE) covers them all. Made from the binary tree by bvh_build (see
   bvh_build_desc.trace_width). An empty slot has min = +inf and max = -inf, which no ray enters. */
typedef struct bvh_node8 {
    float min[3][8], max[3][8]; /* min[axis][slot], max[axis][slot] */
    uint32_t child[8];          /* count 0: index of a bvh_node8 (empty slot: 0) */
    uint8_t count[8];           /* > 0: leaf of count packets from tree.tri4[child] on */
    uint32_t head;              /* the binary node it was made from (bvh_refit and bvh_load ... */
    uint32_t shape;             /* ... follow the grouping from it to the slots: see bvh.h's
                                   8-wide layout section) */
    uint8_t order[8];           /* the grouping's slots by binary index: the j-th is slot order[j]
                                   (all zero: slot j, as files of 0.9.3 and before have it) */
    uint32_t pad[2];
} bvh_node8;

/* Up to four triangles of a wide leaf (160 bytes), by coordinate, so that one SIMD test covers
   them: v[vertex][axis][lane]. Lanes past a leaf's triangles repeat the packet's lane 0 (the same
   primitive: a repeated hit changes nothing). */
typedef struct bvh_tri4 {
    float v[3][3][4];
    uint32_t prim[4]; /* original primitive index of each lane */
} bvh_tri4;

typedef struct bvh_ray {
    bvh_vec3 origin;
    float tmin;   /* hits with tmin <= t <= tmax count; a ray leaving a surface: tmin = 0 from
                     bvh_offset_origin's point, not a tmin > 0 (no epsilon fits every scale) */
    bvh_vec3 dir; /* need not be normalised; t is in units of dir */
    float tmax;
} bvh_ray;

typedef struct bvh_hit {
    float t, u, v; /* distance and barycentrics: p = (1-u-v)*v0 + u*v1 + v*v2 */
    uint32_t prim; /* original triangle/primitive index, BVH_INVALID for a miss */
} bvh_hit;

/* ---- build description -------------------------------------------------------------------- */
/* Both functions or neither: both NULL = BVH_MALLOC / BVH_FREE; one without the other is refused
   (BVH_ERROR_INVALID_ARGUMENT) by every call that takes an allocator. Blocks must be aligned as
   malloc's are. Called only on the thread that called the library, never on its workers: an
   allocator used by one such thread at a time needs no lock (docs/GUIDE.md: a block cache for
   builds every frame). */
typedef struct bvh_allocator {
    void *(*alloc)(size_t size, void *user);
    void (*free)(void *ptr, void *user);
    void *user;
} bvh_allocator;

/* SAH costs: traversal of an interior node, of a leaf, and one primitive intersection.
   All zero means the default (1, 0, 1), the convention all figures of this project use. */
typedef struct bvh_costs {
    float interior, leaf, triangle;
} bvh_costs;

typedef struct bvh_triangles {
    const float *positions; /* x, y, z floats of vertex i at (char*)positions + i*stride */
    size_t stride;          /* bytes between vertices; 0 = 12 (tightly packed); else >= 12 */
    uint32_t vertex_count;
    const uint32_t *indices; /* 3 per triangle; NULL: triangle i is vertices 3i, 3i+1, 3i+2 */
    uint32_t triangle_count;
} bvh_triangles;

/* Options of the ploc builders (ploc, ploc-parallel; others ignore them). Zero = the default
   (bvh_builder_info.ploc). */
typedef struct bvh_ploc_options {
    uint32_t radius;             /* search radius in Morton order; 0 = 16; above 256 refused */
    uint32_t top;                /* when PLOC has merged the n primitives down to n / top clusters
                                    or fewer, a binned-SAH top is built over those (with PLOC's own
                                    split among the candidates) and replaces PLOC's top if its SAH
                                    cost is lower; 0 = 8 (1 acts as 2); BVH_OFF = PLOC alone, as
                                    the paper and the study */
    uint32_t max_bytes_per_prim; /* the tree (nodes + reference indices) at most this many bytes per
                                    primitive; when the SAH collapse gives more, it is redone with
                                    a dearer interior node until the tree fits (larger leaves, a
                                    higher SAH cost; below what leaves of max_leaf_size allow: the
                                    smallest such tree); 0 = 40; BVH_OFF = the SAH alone decides */
} bvh_ploc_options;

/* Options of the sah-midpoint builder (others ignore them). Zero = the default
   (bvh_builder_info.sah_midpoint). */
typedef struct bvh_sah_midpoint_options {
    uint32_t bins;      /* binned SAH object-split candidates per axis costed beside the mid-point
                           plane; 0 = 32; above 64 refused; BVH_OFF = the study's variant
                           (mid-point only) */
    float split_budget; /* extra references allowed, as a fraction of the primitive count; 0 = 0.3;
                           BVH_OFF (2^31 as a float) = no splits; negative, NaN or other values
                           above 1 refused */
} bvh_sah_midpoint_options;

/* The tree optimizer, for every builder (off by default): rounds of parallel reinsertion
   (Meister & Bittner 2018) on the binary tree before its collapse to leaves, on desc.threads (or
   desc.pool) whatever the builder, the same tree for any thread count. Each round a `batch`
   fraction of the nodes (another subset each round) look for the place where they lower the SAH
   most and move there; a node that nearly fills its parent's box is passed over (it would gain
   little). A lower SAH and faster tracing for more build time (docs/DESIGN.md;
   bvhbench's `<builder>+opt` rows: rounds = BENCH_OPT_ROUNDS, batch 0). */
typedef struct bvh_optimize_options {
    uint32_t rounds; /* 0 = off; above 1024 refused */
    float batch;     /* fraction of the binary tree's nodes that may move each round (1 / batch
                        rounds offer every node once); 0 = 0.1; NaN, below 2^-16 or above 1
                        refused */
} bvh_optimize_options;

/* An application's own workers (a job system, TBB, OpenMP...) in place of the library's
   pthreads. run must call task(task_arg, i) exactly once for every i in [0, count), on any of
   its threads, in any order, concurrently or one after another, and return when all have
   returned. A task never waits for one that has not started (at most, briefly, for one that is
   running), so a pool that runs them serially, or on the calling thread, is correct (only
   slower). run is only ever called from the thread that called
   the library, one call at a time per build or batch; it may be called many times per build.
   Zero (run NULL): the library's own pthreads (one thread without them, BVH_NO_THREADS). */
typedef void (*bvh_task_fn)(void *task_arg, uint32_t index);
typedef struct bvh_thread_pool {
    void (*run)(void *user, uint32_t count, bvh_task_fn task, void *task_arg);
    void *user;
} bvh_thread_pool;

/* The description of a build. Zero is the sensible default for every field. */
typedef struct bvh_build_desc {
    bvh_builder builder;
    bvh_triangles triangles; /* either triangles ... */
    const bvh_aabb *boxes;   /* ... or one box per custom primitive (then set box_count) */
    uint32_t box_count;
    uint32_t max_leaf_size; /* 0 = the builder's (bvh_builder_info.max_leaf_size: 4 for top-down
                               and bottom-up, 8 for the SAH-collapsed builders); above 255 refused */
    uint32_t threads;       /* ploc-parallel, sah-midpoint and the optimizer (desc.optimize, any
                               builder): 0 = all online CPUs; above 256 clamped to 256;
                               at most one per 8192 primitives (the tree is the same) */
    bvh_costs costs;        /* build-time SAH costs, zero = (1, 0, 1) (PLOC's collapse: (2.5,
                               0, 1), for half the nodes at a few % SAH); negative/NaN refused */
    int skip_invalid;       /* 0: NaN/Inf geometry is refused with BVH_ERROR_INVALID_GEOMETRY;
                               1: such primitives are left out and counted in tree.excluded */
    uint32_t trace_width;   /* CPU traversal: 0 or 8 = triangle builds add an 8-wide copy of
                               the tree with triangle packets (tree.nodes8, tree.tri4) that
                               bvh_intersect, bvh_occluded and the batch calls use: faster
                               tracing for a few percent of build time; 2 = binary nodes only;
                               anything else is refused */
    bvh_thread_pool pool;   /* run NULL: the library's threads; else every parallel phase is
                               split into `threads` tasks (0 = online CPUs; set it without
                               pthreads) run by pool.run; the tree is the same either way */
    /* progress: NULL = none. Called on the thread that called bvh_build, never concurrently, with
       a fraction from 0 rising to 1 (when the build completes), between stages and steps and
       every 65536 primitives of the serial loops (PROGRESS AND CANCEL above); return nonzero to
       cancel: the build stops soon and returns BVH_ERROR_CANCELLED (tree empty, nothing leaked) */
    int (*progress)(void *user, float fraction);
    void *progress_user;     /* passed to progress */
    bvh_allocator allocator; /* both functions or neither (a half pair is refused) */
    bvh_ploc_options ploc;
    bvh_sah_midpoint_options sah_midpoint;
    bvh_optimize_options optimize;
} bvh_build_desc;

/* ---- the tree ------------------------------------------------------------------------------ */
typedef struct bvh_tree {
    bvh_node *nodes; /* node_count nodes, root at 0 (node_count 0: empty tree) */
    uint32_t node_count;
    uint32_t *prims;    /* ref_count original primitive indices, leaves index into this */
    uint32_t ref_count; /* == prim_count - excluded unless the builder splits references */
    float *tris;        /* triangle builds: 9 floats (v0, v1, v2) per reference, in reference
                           order, for traversal; NULL for box builds */
    bvh_node8 *nodes8;  /* 8-wide nodes for CPU traversal, root at 0; NULL: binary traversal */
    uint32_t node8_count;
    bvh_tri4 *tri4; /* the 8-wide leaves' triangle packets (in nodes8's allocation) */
    uint32_t tri4_count;
    uint32_t prim_count; /* primitives given */
    uint32_t excluded;   /* primitives left out by skip_invalid */
    uint32_t borrowed;   /* 1: nodes, prims and tris are the bytes of a caller's buffer that
                            bvh_load read in place (bvh_load_desc.borrow): bvh_free leaves them,
                            bvh_refit refuses the tree */
    bvh_builder builder;
    bvh_allocator allocator;
} bvh_tree;

typedef struct bvh_stats {
    uint32_t nodes, leaves, refs, max_depth, max_leaf_size;
    size_t bytes;          /* nodes + reference indices */
    size_t triangle_bytes; /* reference-ordered triangle copy used by traversal */
    size_t wide_bytes;     /* the CPU traversal layout: 8-wide nodes and triangle packets */
} bvh_stats;

typedef struct bvh_validation {
    uint32_t node;     /* first offending node, BVH_INVALID if none or not node-specific */
    char message[160]; /* what is wrong, "ok" when valid */
} bvh_validation;

/* The standard camera of the examples and benchmarks: pinhole at the centre of `bounds` +
   normalize(1, 0.6, 1.3) * 1.5 * diagonal, looking at the centre, up (0,1,0), vertical fov 60. */
typedef struct bvh_camera {
    bvh_vec3 eye, forward, right, up; /* right and up are scaled by tan(fov/2) (and aspect) */
    uint32_t width, height;
} bvh_camera;

/* ---- API ----------------------------------------------------------------------------------- */
/* Each fallible call lists the codes it returns; "ARGUMENT" stands for BVH_ERROR_INVALID_ARGUMENT
   and so on. */
BVH_API const char *bvh_result_string(bvh_result r); /* "unknown result code" out of range */
BVH_API const char *bvh_builder_name(bvh_builder b); /* "top-down", "ploc"...; "unknown" */
/* SUCCESS; ARGUMENT: name or out NULL, or no builder of that name. */
BVH_API bvh_result bvh_builder_from_name(const char *name, bvh_builder *out);
/* What a builder does with a zero description: its row of the builder table. */
typedef struct bvh_builder_info {
    const char *name;
    uint32_t max_leaf_size;                /* the default of bvh_build_desc.max_leaf_size */
    float interior_cost;                   /* the default interior cost of its SAH decisions (costs all zero) */
    int uses_threads;                      /* builds on desc.threads (the same tree for any count) */
    int splits_references;                 /* may reference a primitive from several leaves (ref_count > prims) */
    bvh_ploc_options ploc;                 /* the defaults of desc.ploc (zero for builders that ignore it) */
    bvh_sah_midpoint_options sah_midpoint; /* the defaults of desc.sah_midpoint (likewise) */
} bvh_builder_info;
/* BVH_BUILDER_DEFAULT describes the builder it stands for.
   SUCCESS; ARGUMENT: b out of range or out NULL. */
BVH_API bvh_result bvh_builder_get_info(bvh_builder b, bvh_builder_info *out);

/* Builds a tree. On failure *tree is zeroed and nothing is leaked. Every builder stores a node's
   children after the node itself (see bvh_node).
   SUCCESS (also for zero primitives, or all of them left out: an empty tree);
   ARGUMENT: tree or desc NULL, an option out of range, triangles and boxes both given, positions
     or boxes NULL with a count, stride below 12, indices not 4-byte aligned, a half allocator pair
     or one whose blocks are aligned less than malloc's;
   GEOMETRY: a NaN or Inf coordinate, or a box with min > max (unless desc.skip_invalid);
   INDEX_OUT_OF_RANGE: an index >= vertex_count (or vertex_count < 3 * triangle_count without
     indices); TOO_MANY_PRIMITIVES: more than 2^30; OUT_OF_MEMORY: an allocation failed (or the
     caller's allocator gave no block when tried). A worker thread that cannot be created is no
     error: the build runs on those it has, and the tree is the same. */
BVH_API bvh_result bvh_build(bvh_tree *tree, const bvh_build_desc *desc);
/* Releases what bvh_build allocated, with the tree's allocator; zeroes all but tree->allocator.
   NULL and empty trees are ignored. */
BVH_API void bvh_free(bvh_tree *tree);

/* SAH = Ci * sum_I A(n)/A(root) + Cl * sum_L A(n)/A(root) + Ct * sum_L A(n) N(n)/A(root).
   costs NULL or all zero = (1, 0, 1). A tree whose root has zero area uses A(n)/A(root) = 1.
   SUCCESS; ARGUMENT: tree or out_cost NULL, a cost negative or NaN; TREE: the walk from the root
   finds the structure broken (an index out of range, a cycle, nodes not reached exactly once). */
BVH_API bvh_result bvh_sah(const bvh_tree *tree, const bvh_costs *costs, double *out_cost);

/* Checks the structure: every node reached once, children stored after their parent and inside
   its box, leaves contain their primitives (prim_boxes, or the tree's triangles when NULL; for
   split references: overlap), every primitive referenced (exactly once unless the builder
   splits), depth <= BVH_MAX_DEPTH, and the same of the 8-wide copy. report may be NULL.
   SUCCESS; ARGUMENT: tree NULL, a half allocator pair in the tree, or a tree built from boxes
   without its prim_boxes; TREE: a defect, named in report; OUT_OF_MEMORY. */
BVH_API bvh_result bvh_validate(const bvh_tree *tree, const bvh_aabb *prim_boxes, bvh_validation *report);
/* SUCCESS; ARGUMENT: tree or out NULL; TREE: as bvh_sah. */
BVH_API bvh_result bvh_get_stats(const bvh_tree *tree, bvh_stats *out);

/* Closest hit (returns 1 and fills *hit) or 0 with hit->prim = BVH_INVALID. Rays with NaN, a
   zero direction, tmin > tmax or a non-finite origin hit nothing. Ties in t go to the lowest
   primitive index, so that any builder gives exactly the hits of a brute-force loop. A tree
   built from boxes has no triangles to trace: every ray misses, in these calls and in the batch
   calls, which also return BVH_ERROR_NO_TRIANGLES so that the mistake is seen (such a tree is
   traced by bvh_intersect_custom). */
BVH_API int bvh_intersect(const bvh_tree *tree, const bvh_ray *ray, bvh_hit *hit);
/* Any hit in [tmin, tmax]: 1 if the ray is blocked. */
BVH_API int bvh_occluded(const bvh_tree *tree, const bvh_ray *ray);
/* Same as bvh_intersect, counting nodes visited (for heat maps and statistics). */
BVH_API int bvh_intersect_counted(const bvh_tree *tree, const bvh_ray *ray, bvh_hit *hit, uint32_t *nodes_visited);
/* Traces count rays on `threads` threads (0 = all online CPUs).
   SUCCESS; ARGUMENT: tree NULL, rays or the output NULL with count > 0, a half allocator pair
   in the tree; NO_TRIANGLES: a tree built from boxes (every ray missed); OUT_OF_MEMORY: the
   worker threads' bookkeeping could not be allocated. */
BVH_API bvh_result bvh_intersect_batch(const bvh_tree *tree, const bvh_ray *rays, bvh_hit *hits, size_t count,
                                       uint32_t threads);
BVH_API bvh_result bvh_occluded_batch(const bvh_tree *tree, const bvh_ray *rays, uint8_t *occluded, size_t count,
                                      uint32_t threads);
/* The batch calls with options (desc NULL = all zero): the same hits and flags on any pool. */
typedef struct bvh_batch_desc {
    uint32_t threads;     /* threads, or tasks with a pool: 0 = online CPUs (one under
                             BVH_NO_THREADS, which cannot count them: set your pool's size) */
    bvh_thread_pool pool; /* run NULL: the library's threads (see bvh_thread_pool) */
} bvh_batch_desc;
BVH_API bvh_result bvh_intersect_batch_ex(const bvh_tree *tree, const bvh_ray *rays, bvh_hit *hits, size_t count,
                                          const bvh_batch_desc *desc);
BVH_API bvh_result bvh_occluded_batch_ex(const bvh_tree *tree, const bvh_ray *rays, uint8_t *occluded, size_t count,
                                         const bvh_batch_desc *desc);

/* Watertight ray/triangle test (Woop, Benthin & Wald 2013), the one traversal uses. */
BVH_API int bvh_intersect_triangle(const bvh_ray *ray, const float v0[3], const float v1[3], const float v2[3],
                                   bvh_hit *hit);

/* ---- custom primitives ------------------------------------------------------------------- */
/* A tree built from boxes (desc.boxes) is traced with the caller's own intersection test: the
   callback is given the ray, a primitive (the caller's index: the box's position in desc.boxes)
   whose box the ray reaches, and the user pointer. ray->tmax is the closest hit found so far (or
   the caller's tmax): a hit beyond it cannot win, so the test may stop early. It returns 1 and sets
   hit->t (and hit->u, hit->v: the caller's to use, e.g. surface coordinates) for a hit with
   ray->tmin <= t <= ray->tmax, else 0; hit->prim is set by the traversal. A reported t that is
   outside [tmin, tmax], NaN or infinite is ignored (not a hit). Ties in t go to the lowest
   primitive index, as for triangles, so that the hits equal a brute-force loop over the
   primitives with the same callback. On a tree built from triangles the callback decides for each
   triangle instead of the built-in test (alpha-tested triangles: bvh_intersect_triangle on the
   caller's vertices, then the caller's own rejection). The callback may be called more than once
   for one primitive (builders that split references), and from several threads at once in the
   batch calls; it must not modify the tree. */
typedef struct bvh_custom_desc {
    int (*intersect)(const bvh_ray *ray, uint32_t prim, void *user, bvh_hit *hit);
    void *user; /* passed to intersect as is */
} bvh_custom_desc;
/* Closest hit among the tree's primitives by custom->intersect: 1 and *hit filled, or 0 with
   hit->prim = BVH_INVALID and hit->t = ray->tmax. Rays that bvh_intersect refuses (NaN, zero
   direction, tmin > tmax) miss; so does every ray when tree, ray, custom or custom->intersect is
   NULL (the batch calls return BVH_ERROR_INVALID_ARGUMENT for those). */
BVH_API int bvh_intersect_custom(const bvh_tree *tree, const bvh_ray *ray, bvh_hit *hit, const bvh_custom_desc *custom);
/* Any hit in [tmin, tmax] by custom->intersect: 1 if the ray is blocked; stops at the first. */
BVH_API int bvh_occluded_custom(const bvh_tree *tree, const bvh_ray *ray, const bvh_custom_desc *custom);
/* The same for count rays on `threads` threads (0 = all online CPUs).
   SUCCESS; ARGUMENT: tree or custom or custom->intersect NULL, rays or the output NULL with
   count > 0, a half allocator pair in the tree; OUT_OF_MEMORY: as bvh_intersect_batch. */
BVH_API bvh_result bvh_intersect_custom_batch(const bvh_tree *tree, const bvh_ray *rays, bvh_hit *hits, size_t count,
                                              uint32_t threads, const bvh_custom_desc *custom);
BVH_API bvh_result bvh_occluded_custom_batch(const bvh_tree *tree, const bvh_ray *rays, uint8_t *occluded, size_t count,
                                             uint32_t threads, const bvh_custom_desc *custom);
/* The same with options (desc NULL = all zero): threads, or your pool (bvh_batch_desc). */
BVH_API bvh_result bvh_intersect_custom_batch_ex(const bvh_tree *tree, const bvh_ray *rays, bvh_hit *hits, size_t count,
                                                 const bvh_custom_desc *custom, const bvh_batch_desc *desc);
BVH_API bvh_result bvh_occluded_custom_batch_ex(const bvh_tree *tree, const bvh_ray *rays, uint8_t *occluded,
                                                size_t count, const bvh_custom_desc *custom,
                                                const bvh_batch_desc *desc);

/* ---- secondary rays ------------------------------------------------------------------------ */
/* A ray that leaves a surface from its computed hit point may hit that surface again (shadow
   acne): the point is rounded to either side of it. tmin > 0 is no cure at every scale (an
   epsilon right for a unit scene is too small 1e5 away from the origin and too large at 1e-3).
   bvh_offset_origin moves p off the surface along n by a few ulps of p's own coordinates, so
   that it works at any distance from the origin (Waechter & Binder, "A Fast and Robust Method for
   Avoiding Self-Intersection", Ray Tracing Gems, 2019): n is the geometric normal (unit length)
   turned to the side the new ray leaves on (-n for a ray going through the surface); use the
   result as the origin with tmin = 0. p is best computed from the hit's barycentrics
   (bvh_hit_surface), not as origin + t * dir, whose error grows with t. */
BVH_API bvh_vec3 bvh_offset_origin(bvh_vec3 p, bvh_vec3 n);
/* The point of triangle hit->prim of mesh (the triangles given to bvh_build) at the hit's
   barycentrics, (1 - u - v) v0 + u v1 + v v2, and its unit geometric normal, the normalised
   (v1 - v0) x (v2 - v0) (zero for a zero-area triangle). Either output may be NULL.
   SUCCESS; ARGUMENT: mesh or hit NULL, positions NULL, stride below 12, hit->prim >= the triangle
   count (a miss included); INDEX_OUT_OF_RANGE: an index of the triangle >= vertex_count. */
BVH_API bvh_result bvh_hit_surface(const bvh_triangles *mesh, const bvh_hit *hit, bvh_vec3 *point, bvh_vec3 *normal);

/* ---- instances: two-level scenes ------------------------------------------------------------ */
/* A scene places bottom-level trees (one per mesh, built by bvh_build, any builder) in the world
   by instances, under a top-level tree over the instances' world boxes (a box tree, built by
   bvh_build). Tracing transforms the ray into each instance's space it reaches (origin and
   direction, not normalised: t stays in world units) and traces the instance's tree there. A
   bottom-level tree built from boxes (custom primitives: spheres, curves...) is traced by the
   instance's bvh_custom_desc, given the ray in the instance's space, as bvh_intersect_custom
   does; a triangle tree with one lets the callback decide for each triangle (alpha testing).
   Rebuild the scene (bvh_scene_build) when instances move; the bottom-level trees are not
   touched. */
typedef struct bvh_instance {
    const bvh_tree *tree;          /* bottom level; must stay valid (and unchanged) while the scene is used */
    float transform[12];           /* object to world, row-major 3x4: world = M * local + (m[3], m[7], m[11]),
                                      M = rows (m[0..2]), (m[4..6]), (m[8..10]); finite and invertible */
    uint32_t id;                   /* the caller's, reported in hits */
    uint32_t mask;                 /* a ray whose mask shares no bit with it skips the instance */
    const bvh_custom_desc *custom; /* NULL: the tree's triangles. Else the primitives' test (a tree
                                      built from boxes needs one); the desc must stay valid while
                                      the scene is used, and is called as bvh_intersect_custom's */
} bvh_instance;
typedef struct bvh_scene_desc {
    const bvh_instance *instances; /* copied: the array may be freed when bvh_scene_build returns */
    uint32_t instance_count;
    bvh_builder builder;     /* top level (0 = the default builder) */
    uint32_t threads;        /* as bvh_build_desc.threads */
    bvh_allocator allocator; /* both functions or neither; kept by the scene */
    bvh_thread_pool pool;    /* as bvh_build_desc.pool (the top level's build) */
} bvh_scene_desc;
typedef struct bvh_scene {
    bvh_tree top;            /* over the instances' world boxes; prims = instance indices */
    bvh_instance *instances; /* instance_count copies of desc.instances */
    float *inverse;          /* 12 floats per instance: world to object (bvh_ray_transform) */
    bvh_aabb *boxes;         /* per instance: its world box (the boxes the top level was built on) */
    bvh_node8 *top8;         /* the top level as CPU tracing reads it: 8-wide nodes whose leaf
                                slots hold one instance each (child: its index; count 1, or 2
                                where its transform is the identity), its box the slot's; built
                                from top by bvh_scene_build */
    uint32_t top8_count;
    uint32_t instance_count;
    uint32_t *mesh;        /* per instance: its tree's number among the distinct trees */
    size_t *ref_base;      /* per distinct tree: its first entry in ref_of_prim */
    uint32_t *ref_of_prim; /* per distinct tree, prim_count entries: a reference of each
                              triangle (tree.tris + 9 * ref), for the hit's normal */
    uint32_t mesh_count;
    bvh_allocator allocator;
} bvh_scene;
typedef struct bvh_scene_hit {
    float t, u, v;     /* world t (units of the world ray's dir), barycentrics in the triangle */
    uint32_t instance; /* index into desc.instances; BVH_INVALID for a miss */
    uint32_t id;       /* that instance's id */
    uint32_t prim;     /* the triangle's (or custom primitive's) index in its mesh (the
                          bottom-level build's input) */
    bvh_vec3 normal;   /* unit geometric normal in world space: (v1 - v0) x (v2 - v0) in object
                          space, by the inverse transpose of M; zero for a miss and for a custom
                          primitive of a box tree (its normal is the caller's: prim, u, v, t) */
} bvh_scene_hit;
/* SUCCESS (also for zero instances); ARGUMENT: scene or desc NULL, instances NULL with a count,
   an instance whose tree is NULL, or was built from boxes and has no custom test (custom or
   custom->intersect NULL), a half allocator pair, a builder out of range; GEOMETRY: a transform with a NaN or Inf, or
   singular (no inverse in float); TOO_MANY_PRIMITIVES: more than 2^30 instances; OUT_OF_MEMORY. On failure *scene is
   zeroed and nothing is leaked. An instance of an empty tree is never hit. */
BVH_API bvh_result bvh_scene_build(bvh_scene *scene, const bvh_scene_desc *desc);
/* Releases what bvh_scene_build allocated (not the bottom-level trees). NULL is ignored. */
BVH_API void bvh_scene_free(bvh_scene *scene);
/* Closest hit over all instances whose mask shares a bit with `mask` (~0u: all): 1 and *hit
   filled, or 0 with hit->instance = BVH_INVALID, hit->t = ray->tmax. Ties in t go to the lowest
   instance index, then to the lowest triangle index, so the hits equal a brute-force loop over
   the instances (in order) that traces each with the ray bvh_ray_transform gives. */
BVH_API int bvh_scene_intersect(const bvh_scene *scene, const bvh_ray *ray, uint32_t mask, bvh_scene_hit *hit);
/* Any hit in [tmin, tmax] over the instances `mask` selects: 1 if the ray is blocked. */
BVH_API int bvh_scene_occluded(const bvh_scene *scene, const bvh_ray *ray, uint32_t mask);
/* bvh_scene_intersect and bvh_scene_occluded over count rays with one mask, on desc's threads or
   pool (desc NULL: all online CPUs, the library's threads), as bvh_intersect_batch_ex: the same
   hits (every field, to the bit) and flags as the single-ray calls, on any thread count or pool.
   Rays with different masks go in separate calls, as on OpenCL (cl/bvh_cl.h).
   SUCCESS; ARGUMENT: scene NULL, rays or the output NULL with count > 0, a half allocator pair in
   the scene; OUT_OF_MEMORY: the worker threads' bookkeeping could not be allocated. */
BVH_API bvh_result bvh_scene_intersect_batch(const bvh_scene *scene, const bvh_ray *rays, uint32_t mask,
                                             bvh_scene_hit *hits, size_t count, const bvh_batch_desc *desc);
BVH_API bvh_result bvh_scene_occluded_batch(const bvh_scene *scene, const bvh_ray *rays, uint32_t mask,
                                            uint8_t *occluded, size_t count, const bvh_batch_desc *desc);
/* The ray in the space of the 3x4 transform m (row-major, as bvh_instance.transform): origin
   M o + (m[3], m[7], m[11]), direction M d, not normalised, so that t means the same point in
   both spaces; tmin and tmax unchanged. Tracing uses it with scene->inverse + 12 * instance. */
BVH_API bvh_ray bvh_ray_transform(const bvh_ray *ray, const float m[12]);

/* The tree's bounds (empty box for an empty tree). */
BVH_API bvh_aabb bvh_tree_bounds(const bvh_tree *tree);

/* width or height 0 is taken as 1. */
BVH_API bvh_camera bvh_camera_standard(bvh_aabb bounds, uint32_t width, uint32_t height);
/* Primary ray through the centre of pixel (x, y), y = 0 at the top; unit direction. */
BVH_API bvh_ray bvh_camera_ray(const bvh_camera *cam, uint32_t x, uint32_t y);

/* ---- refit -------------------------------------------------------------------------------- */
/* New positions for the primitives of a built tree: the same triangles (the shape of the build's
   bvh_build_desc.triangles: triangle_count = tree.prim_count, indices naming the same vertices)
   with moved vertices, or one new box per primitive of a box tree (box_count = tree.prim_count).
   The buffers may differ from the build's (and may be freed after the call). */
typedef struct bvh_refit_desc {
    bvh_triangles triangles; /* a triangle tree's new triangles ... */
    const bvh_aabb *boxes;   /* ... or a box tree's new boxes (then set box_count) */
    uint32_t box_count;
    uint32_t threads;     /* 0 = all online CPUs; at most one per 8192 references */
    bvh_thread_pool pool; /* zero = the library's threads; else `threads` tasks on yours */
} bvh_refit_desc;
/* Refits a built (or loaded) tree to moved primitives, keeping its topology: every binary node
   box bottom-up, tree.tris, and the 8-wide layout's boxes and packets updated in place with the
   grouping the build chose (so its node and packet counts stay). Arrays keep their addresses and sizes; the tree
   gives the same hits as a brute-force loop over the new triangles. The quality falls as the
   motion departs from the build's: rebuild when bvh_sah has grown too much.
   - Split references (sah-midpoint): refitted correctly, each reference's leaf box taking the
     whole triangle's box (the clipping is not redone): valid and exact, with more overlap.
   - skip_invalid trees: the excluded primitives stay out (their new positions are not read).
   - Errors leave the tree unchanged: BVH_ERROR_INVALID_ARGUMENT (a NULL pointer, a count or kind
     that differs from the tree's, stride < 12, a tree bvh_load borrowed from a buffer),
     BVH_ERROR_INDEX_OUT_OF_RANGE, BVH_ERROR_INVALID_GEOMETRY (NaN or Inf in a vertex of a
     primitive the tree holds, or an inverted box: the build's policy). A tree that fails
     bvh_validate may be refused with BVH_ERROR_INVALID_TREE after part of it was updated.
   - Memory: nothing is allocated but the thread team's bookkeeping (a few bytes per thread, from
     the tree's allocator; without it the refit runs on one thread), so it cannot run out of
     memory; 20 KiB of stack per thread. Each 8-wide node keeps, from its build, its grouping
     (bvh_node8.head, .shape, in what was padding: no memory per triangle); the refit follows it
     in one pass over the 8-wide layout rather than regrouping by the new areas.
   - Threads: desc.threads, parallel over subtrees; the result does not depend on the count. */
BVH_API bvh_result bvh_refit(bvh_tree *tree, const bvh_refit_desc *desc);

/* ---- save and load ------------------------------------------------------------------------ */
/* A tree as bytes: a 64-byte header (magic "BVH.TREE", format version 2, byte-order marker,
   builder, counts, payload size, a header and a payload checksum) then the binary nodes, the
   references and, for triangle trees, tree.tris and the 8-wide nodes (with their groupings), in
   the saving machine's byte order: about 58 to 65 bytes per triangle for a default build. The
   8-wide packets are not stored: bvh_load remakes them from tree.tris and the groupings,
   checking each against the binary tree. Version 1 files (bvh.h 0.6.0) are refused with
   BVH_ERROR_UNSUPPORTED_FORMAT: load them with 0.6.0's bvh.h or rebuild, and save again.
   The callbacks return the number of bytes they moved; fewer than asked ends the call. */
typedef size_t (*bvh_write_fn)(void *user, const void *data, size_t size);
typedef size_t (*bvh_read_fn)(void *user, void *data, size_t size);
/* Writes the tree through `write` (BVH_ERROR_IO if it takes fewer bytes than given). */
BVH_API bvh_result bvh_save(const bvh_tree *tree, bvh_write_fn write, void *user);
/* The bytes bvh_save writes for this tree (0 for a NULL tree). */
BVH_API size_t bvh_save_size(const bvh_tree *tree);
typedef struct bvh_load_desc {
    bvh_read_fn read; /* either a stream ... */
    void *user;
    const void *data; /* ... or a memory buffer of `size` bytes (then read is NULL) */
    size_t size;
    uint32_t borrow;         /* with data: 1 = the tree's binary nodes, references and triangles
                                are the buffer's own bytes, read in place (no copy, no memory
                                for them): see bvh_load; 0 = copies */
    size_t max_bytes;        /* refuse a tree whose payload is larger (BVH_ERROR_CORRUPT) before
                                allocating it; 0 = no limit but the format's own caps (with a
                                memory buffer its size bounds the payload in any case) */
    uint32_t trace_width;    /* 0 = as the saved tree had it; 8 = the 8-wide layout (made as bvh_build
                                does if the file has none); 2 = none */
    uint32_t threads;        /* a memory buffer's copy and checks, and the 8-wide layout: 0 = all
                                online CPUs */
    bvh_allocator allocator; /* becomes the tree's, as bvh_build_desc.allocator */
    bvh_thread_pool pool;    /* zero = the library's threads; else `threads` tasks on yours */
} bvh_load_desc;
/* Reads a tree saved by bvh_save. Sizes are checked before anything is allocated; the checksums,
   then the structure (bvh_validate's checks in linear passes, and the 8-wide groupings against
   the binary tree; a box tree's leaves are not checked against boxes it does not have) are
   checked before the tree is returned. On failure *tree is zeroed and
   nothing is leaked. Errors: BVH_ERROR_TRUNCATED, BVH_ERROR_CORRUPT,
   BVH_ERROR_UNSUPPORTED_FORMAT, BVH_ERROR_OUT_OF_MEMORY, BVH_ERROR_INVALID_ARGUMENT.
   desc.borrow (a memory buffer only, 4-byte aligned, else BVH_ERROR_INVALID_ARGUMENT): the same
   checks, read where the bytes lie; tree.nodes, .prims and .tris then point into the buffer
   (tree.borrowed = 1) and only the 8-wide layout is allocated (a file saved by bvh_save, read or
   mapped whole, e.g. with mmap: the tree then allocates 40-45% of a copy's bytes). The buffer must
   stay alive and unchanged until bvh_free, which leaves it alone; bvh_load never writes to it.
   bvh_refit refuses such a tree (BVH_ERROR_INVALID_ARGUMENT): load a copy to move it. */
BVH_API bvh_result bvh_load(bvh_tree *tree, const bvh_load_desc *desc);

/* AABB helpers */
BVH_API bvh_aabb bvh_aabb_empty(void);
BVH_API void bvh_aabb_grow(bvh_aabb *box, bvh_vec3 p);
BVH_API bvh_aabb bvh_aabb_merge(bvh_aabb a, bvh_aabb b);
BVH_API float bvh_aabb_area(bvh_aabb box); /* 0 for an empty box */
BVH_API bvh_vec3 bvh_aabb_centroid(bvh_aabb box);
BVH_API int bvh_aabb_contains(bvh_aabb outer, bvh_aabb inner);

#ifdef __cplusplus
}
#endif
#endif /* BVH_H_INCLUDED */

/* ============================================================================================ */
/*                                      IMPLEMENTATION                                          */
/* ============================================================================================ */
#ifdef BVH_IMPLEMENTATION
#ifndef BVH_IMPLEMENTATION_DONE
#define BVH_IMPLEMENTATION_DONE

#include <float.h>
#include <string.h>
#ifndef BVH_ASSERT
#include <assert.h>
#define BVH_ASSERT(c) assert(c)
#endif
#if defined(BVH_MALLOC) != defined(BVH_FREE)
#error "bvh.h: define both BVH_MALLOC and BVH_FREE, or neither"
#endif
#ifndef BVH_MALLOC
#include <stdlib.h>
#define BVH_MALLOC(size, user) ((void)(user), malloc(size))
#define BVH_FREE(ptr, user) ((void)(user), free(ptr))
#define BVH__DEFAULT_MALLOC
#endif
#if defined(__linux__) && defined(BVH__DEFAULT_MALLOC) && !defined(BVH_NO_HUGEPAGES)
#include <sys/mman.h>
#if defined(MADV_HUGEPAGE)
#define BVH__MADV_HUGEPAGE MADV_HUGEPAGE
#elif !defined(__cplusplus) && (defined(__x86_64__) || defined(__i386__) || defined(__aarch64__) || defined(__riscv))
/* An ISO-only dialect (-std=c11, no _DEFAULT_SOURCE before the first system header) hides
   madvise and its flags in <sys/mman.h>, and the advice would silently go: the call and the
   flag's value (14 in the kernel's generic and x86 headers) declared here, so that the dialect
   does not change what a build or a load costs (docs/bench, 0.9.14). */
extern int madvise(void *addr, size_t length, int advice);
#define BVH__MADV_HUGEPAGE 14
#endif
#endif
/* The implementation keeps IEEE semantics whatever the floating-point flags of the file that
   includes it (-ffast-math, -Ofast, -ffp-contract=fast): its input checks must see NaN and Inf,
   its traversal relies on Inf boxes and on the order of NaN in min and max, and the SIMD and
   scalar tests must give the same bits as the brute-force loop. gcc switches the flags off for
   the implementation's functions. clang's pragmas cannot undo -ffinite-math-only nor the fused
   multiply-adds of -ffp-contract=fast, so it refuses -ffast-math; -ffp-contract=fast alone,
   which no macro reveals, must be left off for this file by the user (README: compiler flags). */
#if defined(__clang__)
#if defined(__FAST_MATH__) || (defined(__FINITE_MATH_ONLY__) && __FINITE_MATH_ONLY__)
#error                                                                                                                 \
    "bvh.h: clang cannot keep IEEE semantics for BVH_IMPLEMENTATION under -ffast-math / -Ofast: compile the file that defines BVH_IMPLEMENTATION with -fno-fast-math (your other files may keep -ffast-math), or use gcc"
#endif
#pragma float_control(precise, on, push)
#pragma clang fp contract(off)
#define BVH__FP_POP _Pragma("float_control(pop)")
#endif
#if !defined(BVH_NO_SIMD) && (defined(__SSE2__) || defined(_M_X64) || (defined(_M_IX86_FP) && _M_IX86_FP >= 2))
#include <emmintrin.h>
#define BVH__SSE 1
#endif
#if defined(BVH__SSE) && !defined(BVH_NO_AVX2) && (defined(__x86_64__) || defined(__i386__)) &&                        \
    (defined(__GNUC__) || defined(__clang__))
#include <immintrin.h>
#define BVH__AVX2 1 /* compiled for AVX2 on its own (target attribute), used when the CPU has it */
#endif
/* A function whose only effect is BVH__PREFETCH must be BVH__INLINE: gcc 12 takes such a function
   for pure and drops every call of it that it does not inline, prefetches and all. */
#if defined(__GNUC__) || defined(__clang__)
#define BVH__PREFETCH(p) __builtin_prefetch(p)
#elif defined(BVH__SSE)
#define BVH__PREFETCH(p) _mm_prefetch((const char *)(p), _MM_HINT_T0)
#else
#define BVH__PREFETCH(p) ((void)0)
#endif
/* Hides an integer's value from the optimizer, so that a select made of masks stays masks. */
#if defined(__GNUC__) || defined(__clang__)
#define BVH__OPAQUE(x) __asm__("" : "+r"(x))
#else
#define BVH__OPAQUE(x) ((void)0)
#endif
#ifndef BVH_NO_THREADS
#include <pthread.h>
#include <unistd.h>
#endif

#ifdef __cplusplus
#define BVH__CAST(T, x) static_cast<T>(x)
#else
#define BVH__CAST(T, x) ((T)(x))
#endif

#if defined(__GNUC__) || defined(__clang__)
#define BVH__INLINE static inline __attribute__((always_inline))
#else
#define BVH__INLINE static inline
#endif
#define BVH__MAX_PRIMS (1u << 30) /* keeps 2n nodes and split references inside uint32 */
#define BVH__MAX_LEAF 255u
#define BVH__MAX_THREADS 256u
#define BVH__W 8u /* slots of a wide node (bvh_node8) */

#if defined(__GNUC__) &&                                                                                               \
    !defined(__clang__) /* after the system headers: their inline functions keep their own options */
#pragma GCC push_options
#pragma GCC optimize("no-fast-math", "fp-contract=off")
#define BVH__FP_POP _Pragma("GCC pop_options")
#elif !defined(__clang__)
#define BVH__FP_POP
#endif

/* ============================================================================================ */
/* == math and AABB ============================================================================ */
/* ============================================================================================ */
BVH__INLINE float bvh__minf(float a, float b) { return a < b ? a : b; }
BVH__INLINE float bvh__maxf(float a, float b) { return a > b ? a : b; }
BVH__INLINE float bvh__get(bvh_vec3 v, int axis) { return axis == 0 ? v.x : axis == 1 ? v.y : v.z; }
/* Coordinate `axis` of a vector in memory, as one indexed load or store (bvh_vec3 is three
   floats without padding: checked below). */
BVH__INLINE float bvh__at(const bvh_vec3 *v, int axis) {
    float x;
    memcpy(&x, BVH__CAST(const char *, (const void *)v) + (size_t)axis * sizeof x, sizeof x);
    return x;
}
BVH__INLINE void bvh__set(bvh_vec3 *v, int axis, float x) {
    memcpy(BVH__CAST(char *, (void *)v) + (size_t)axis * sizeof x, &x, sizeof x);
}
typedef char bvh__vec3_is_packed[sizeof(bvh_vec3) == 3 * sizeof(float) ? 1 : -1];
/* NaN and Inf by their bits: no floating-point flag can fold these tests away. */
static uint32_t bvh__bits(float f) {
    uint32_t u;
    memcpy(&u, &f, sizeof u);
    return u;
}
static int bvh__finite(float f) { return (bvh__bits(f) & 0x7f800000u) != 0x7f800000u; }
static int bvh__nan(float f) { return (bvh__bits(f) & 0x7fffffffu) > 0x7f800000u; }
static int bvh__finite3(const float *p) { return bvh__finite(p[0]) && bvh__finite(p[1]) && bvh__finite(p[2]); }

/* The builders' box operations, inlined in their loops; the public functions wrap them. The
   accumulating box is always the first operand, so that min/max pick alike between -0 and +0. */
BVH__INLINE bvh_aabb bvh__empty(void) {
    bvh_aabb b;
    b.min.x = b.min.y = b.min.z = BVH_INF;
    b.max.x = b.max.y = b.max.z = -BVH_INF;
    return b;
}
BVH_API bvh_aabb bvh_aabb_empty(void) { return bvh__empty(); }
BVH__INLINE void bvh__grow(bvh_aabb *b, bvh_vec3 p) {
    b->min.x = bvh__minf(b->min.x, p.x);
    b->max.x = bvh__maxf(b->max.x, p.x);
    b->min.y = bvh__minf(b->min.y, p.y);
    b->max.y = bvh__maxf(b->max.y, p.y);
    b->min.z = bvh__minf(b->min.z, p.z);
    b->max.z = bvh__maxf(b->max.z, p.z);
}
BVH__INLINE bvh_aabb bvh__merge(bvh_aabb a, bvh_aabb b) {
    bvh_aabb r;
    r.min.x = bvh__minf(a.min.x, b.min.x);
    r.max.x = bvh__maxf(a.max.x, b.max.x);
    r.min.y = bvh__minf(a.min.y, b.min.y);
    r.max.y = bvh__maxf(a.max.y, b.max.y);
    r.min.z = bvh__minf(a.min.z, b.min.z);
    r.max.z = bvh__maxf(a.max.z, b.max.z);
    return r;
}
BVH_API void bvh_aabb_grow(bvh_aabb *b, bvh_vec3 p) { bvh__grow(b, p); }
BVH_API bvh_aabb bvh_aabb_merge(bvh_aabb a, bvh_aabb b) { return bvh__merge(a, b); }
static float bvh__half_area(bvh_aabb b) {
    float dx = b.max.x - b.min.x, dy = b.max.y - b.min.y, dz = b.max.z - b.min.z;
    if (!(dx >= 0.0f && dy >= 0.0f && dz >= 0.0f)) return 0.0f; /* empty (or NaN) box */
    return dx * dy + dy * dz + dz * dx;
}
BVH_API float bvh_aabb_area(bvh_aabb b) { return 2.0f * bvh__half_area(b); }
/* Half the surface area in double, for costs summed over many boxes and for boxes near FLT_MAX
   (whose float area would overflow); 0 for an empty box. */
static double bvh__half_area_d(bvh_aabb b) {
    double dx = (double)b.max.x - b.min.x;
    double dy = (double)b.max.y - b.min.y;
    double dz = (double)b.max.z - b.min.z;
    if (!(dx >= 0.0 && dy >= 0.0 && dz >= 0.0)) return 0.0;
    return dx * dy + dy * dz + dz * dx;
}
BVH__INLINE bvh_vec3 bvh__centroid(bvh_aabb b) {
    bvh_vec3 c;
    c.x = 0.5f * (b.min.x + b.max.x);
    c.y = 0.5f * (b.min.y + b.max.y);
    c.z = 0.5f * (b.min.z + b.max.z);
    return c;
}
BVH_API bvh_vec3 bvh_aabb_centroid(bvh_aabb b) { return bvh__centroid(b); }
BVH_API int bvh_aabb_contains(bvh_aabb o, bvh_aabb i) {
    return o.min.x <= i.min.x && o.min.y <= i.min.y && o.min.z <= i.min.z && o.max.x >= i.max.x && o.max.y >= i.max.y &&
           o.max.z >= i.max.z;
}
static int bvh__nonempty(bvh_aabb b) { return b.min.x <= b.max.x && b.min.y <= b.max.y && b.min.z <= b.max.z; }
static bvh_aabb bvh__node_box(const bvh_node *n) {
    bvh_aabb b;
    b.min = n->min;
    b.max = n->max;
    return b;
}
static void bvh__set_box(bvh_node *n, bvh_aabb b) {
    n->min = b.min;
    n->max = b.max;
}
BVH__INLINE bvh_aabb bvh__tri_box(const float *t) {
    bvh_aabb b;
    b.min.x = bvh__minf(bvh__minf(t[0], t[3]), t[6]);
    b.max.x = bvh__maxf(bvh__maxf(t[0], t[3]), t[6]);
    b.min.y = bvh__minf(bvh__minf(t[1], t[4]), t[7]);
    b.max.y = bvh__maxf(bvh__maxf(t[1], t[4]), t[7]);
    b.min.z = bvh__minf(bvh__minf(t[2], t[5]), t[8]);
    b.max.z = bvh__maxf(bvh__maxf(t[2], t[5]), t[8]);
    return b;
}

/* ============================================================================================ */
/* == names ===================================================================================== */
/* ============================================================================================ */
BVH_API const char *bvh_result_string(bvh_result r) {
    switch (r) {
    case BVH_SUCCESS:
        return "success";
    case BVH_ERROR_INVALID_ARGUMENT:
        return "invalid argument (NULL pointer or option out of range)";
    case BVH_ERROR_INVALID_GEOMETRY:
        return "invalid geometry (NaN or Inf coordinate, or inverted box)";
    case BVH_ERROR_INDEX_OUT_OF_RANGE:
        return "triangle index out of range of the vertex count";
    case BVH_ERROR_TOO_MANY_PRIMITIVES:
        return "too many primitives for 32-bit references";
    case BVH_ERROR_OUT_OF_MEMORY:
        return "out of memory";
    case BVH_ERROR_THREAD:
        return "could not create a worker thread";
    case BVH_ERROR_INVALID_TREE:
        return "invalid tree (see the validation report)";
    case BVH_ERROR_NO_TRIANGLES:
        return "the tree was built from boxes and has no triangles to trace";
    case BVH_ERROR_CANCELLED:
        return "the build was cancelled by its progress callback";
    case BVH_ERROR_IO:
        return "the write callback took fewer bytes than given";
    case BVH_ERROR_TRUNCATED:
        return "the saved tree ends early (truncated data)";
    case BVH_ERROR_CORRUPT:
        return "not a saved tree, or a damaged one (checksum, sizes or structure)";
    case BVH_ERROR_UNSUPPORTED_FORMAT:
        return "a saved tree of another format version or byte order";
    default:
        return "unknown result code";
    }
}

/* ============================================================================================ */
/* == memory ==================================================================================== */
/* ============================================================================================ */

/* Blocks must be aligned as malloc's are (BVH__ALIGN): the library stores structs in them. A
   caller allocator's block aligned less is given back and counts as a failed allocation;
   bvh_build refuses such an allocator up front (bvh__allocator_ok). */
#define BVH__ALIGN (sizeof(void *) >= 8 ? 16u : 8u)
static void *bvh__alloc(const bvh_allocator *al, size_t count, size_t elem) {
    size_t size;
    void *p;
    if (count == 0) count = 1;
    if (count > (size_t)-1 / elem) return NULL;
    size = count * elem;
    if (al->alloc) {
        p = al->alloc(size, al->user);
        if (p && (uintptr_t)p % BVH__ALIGN) {
            al->free(p, al->user);
            return NULL;
        }
        return p;
    }
    p = BVH_MALLOC(size, al->user);
#if defined(__linux__) && defined(BVH__DEFAULT_MALLOC) && !defined(BVH_NO_HUGEPAGES) && defined(BVH__MADV_HUGEPAGE)
    /* Big build arrays and the tree itself are touched once each, at random (sort scatter, node
       emission, traversal): transparent huge pages take most of the page faults and TLB misses
       out (docs/DESIGN.md, Memory). Only the whole 2 MiB pages inside the block are advised. */
    if (p && size >= ((size_t)4 << 20)) {
        const uintptr_t huge = (uintptr_t)1 << 21;
        uintptr_t b = ((uintptr_t)p + huge - 1) & ~(huge - 1), e = ((uintptr_t)p + size) & ~(huge - 1);
        if (e > b) (void)madvise((void *)b, (size_t)(e - b), BVH__MADV_HUGEPAGE);
    }
#endif
    return p;
}
static void bvh__free(const bvh_allocator *al, void *p) {
    if (!p) return;
    if (al->free)
        al->free(p, al->user);
    else
        BVH_FREE(p, al->user);
}
#define BVH__ALLOC(al, T, n) BVH__CAST(T *, bvh__alloc((al), (size_t)(n), sizeof(T)))
/* Both functions or neither: a half pair would hand the caller's blocks to BVH_FREE or malloc's to
   the caller. Every public call that takes an allocator (a desc's or a tree's) checks it. */
static int bvh__allocator_paired(const bvh_allocator *al) { return !al->alloc == !al->free; }
/* A caller allocator, tried once: BVH_ERROR_INVALID_ARGUMENT if it is a half pair or its blocks
   are aligned less than malloc's, BVH_ERROR_OUT_OF_MEMORY if it gives none. */
static bvh_result bvh__allocator_ok(const bvh_allocator *al) {
    void *p;
    if (!bvh__allocator_paired(al)) return BVH_ERROR_INVALID_ARGUMENT;
    if (!al->alloc) return BVH_SUCCESS;
    if (!(p = al->alloc(64, al->user))) return BVH_ERROR_OUT_OF_MEMORY;
    al->free(p, al->user);
    return (uintptr_t)p % BVH__ALIGN ? BVH_ERROR_INVALID_ARGUMENT : BVH_SUCCESS;
}
/* A block aligned to 128 bytes (the wide layout: a 256-byte node then spans four cache lines, not
   five, in two of the pairs that the CPU's adjacent-line prefetch fetches together). The byte
   before the returned pointer holds its distance from the allocation. */
static void *bvh__alloc_lines(const bvh_allocator *al, size_t size) {
    unsigned char *raw, *p;
    if (size > (size_t)-1 - 128) return NULL;
    if (!(raw = BVH__ALLOC(al, unsigned char, size + 128))) return NULL;
    p = raw + (128 - ((uintptr_t)raw & 127u));
    p[-1] = (unsigned char)(p - raw);
    return p;
}
static void bvh__free_lines(const bvh_allocator *al, void *p) {
    unsigned char *q = BVH__CAST(unsigned char *, p);
    if (q) bvh__free(al, q - q[-1]);
}
#ifndef BVH__MIN_PRIMS_PER_THREAD /* private; the tests set it to 1 to run small inputs threaded */
#define BVH__MIN_PRIMS_PER_THREAD 8192u
#endif

/* ============================================================================================ */
/* == threads =================================================================================== */
/* A team runs one function on n threads (the caller is thread 0) that meet at barriers; threads
   are created once per call, never per iteration. If a thread cannot be created the team runs
   with the threads it has (the work is split by the final count, so results do not change). */
/* ============================================================================================ */
typedef struct bvh__team bvh__team;
typedef void (*bvh__team_fn)(void *arg, uint32_t tid, uint32_t nthreads, bvh__team *team);
struct bvh__team {
    bvh__team_fn fn;
    void *arg;
    uint32_t n;
    const bvh_thread_pool *pool; /* non-NULL: the n threads are tasks of a caller's pool */
#ifndef BVH_NO_THREADS
    pthread_mutex_t mutex;
    pthread_cond_t cond;
    uint32_t waiting, generation, started;
    int spin; /* rounds to spin at a barrier: 0 when the team has more threads than CPUs */
#endif
};
typedef struct bvh__worker {
    bvh__team *team;
    uint32_t tid;
} bvh__worker;

static uint32_t bvh__cpu_count(void) {
#ifndef BVH_NO_THREADS
    long n = sysconf(_SC_NPROCESSORS_ONLN);
    if (n < 1) return 1;
    return n > (long)BVH__MAX_THREADS ? BVH__MAX_THREADS : (uint32_t)n;
#else
    return 1;
#endif
}
static uint32_t bvh__resolve_threads(uint32_t t) {
    if (t == 0) return bvh__cpu_count();
    return t > BVH__MAX_THREADS ? BVH__MAX_THREADS : t;
}

/* Barrier. The last thread to arrive bumps the generation; the others spin on it for a few
   microseconds before they sleep on the condition variable: a PLOC iteration on a mid-size
   scene is shorter than a sleeping thread takes to wake up. A team
   with more threads than CPUs does not spin: a spinning thread would hold a CPU that a working
   one needs. With compilers that lack the GCC atomic builtins they
   sleep at once. */
#if defined(__GNUC__) || defined(__clang__)
#define BVH__LOAD_ACQ(p) __atomic_load_n((p), __ATOMIC_ACQUIRE)
#define BVH__STORE_REL(p, v) __atomic_store_n((p), (v), __ATOMIC_RELEASE)
#define BVH__SPIN_ROUNDS 20000 /* with a pause each: up to about half a millisecond */
#if defined(__x86_64__) || defined(__i386__)
#define BVH__PAUSE() __builtin_ia32_pause()
#endif
#else
#define BVH__LOAD_ACQ(p) (*(p))
#define BVH__STORE_REL(p, v) (*(p) = (v))
#define BVH__SPIN_ROUNDS 0
#endif
#ifndef BVH__PAUSE
#define BVH__PAUSE() ((void)0)
#endif
static void bvh__team_sync(bvh__team *team) {
#ifndef BVH_NO_THREADS
    uint32_t gen;
    int k;
    BVH_ASSERT(!team->pool || team->n <= 1); /* pool tasks never meet (bvh__team_run_on) */
    if (team->n <= 1 || team->pool) return;
    pthread_mutex_lock(&team->mutex);
    gen = team->generation;
    if (++team->waiting == team->n) {
        team->waiting = 0;
        BVH__STORE_REL(&team->generation, gen + 1);
        pthread_cond_broadcast(&team->cond);
        pthread_mutex_unlock(&team->mutex);
        return;
    }
    pthread_mutex_unlock(&team->mutex);
    for (k = 0; k < team->spin; k++) {
        if (BVH__LOAD_ACQ(&team->generation) != gen) return;
        BVH__PAUSE();
    }
    pthread_mutex_lock(&team->mutex);
    while (BVH__LOAD_ACQ(&team->generation) == gen) pthread_cond_wait(&team->cond, &team->mutex);
    pthread_mutex_unlock(&team->mutex);
#else
    (void)team;
#endif
}

/* Streamed stores (bvh__packets_write) fenced: in memory before anything this thread stores or
   synchronises with after it. */
BVH__INLINE void bvh__stream_fence(void) {
#ifdef BVH__SSE
    _mm_sfence();
#endif
}
/* A thread's part of a team's pass, its streamed stores fenced at the end: so they are in memory
   before the pass's end is seen, by the team's barrier or join or by a caller's pool. */
BVH__INLINE void bvh__team_fn_run(bvh__team *team, uint32_t tid) {
    team->fn(team->arg, tid, team->n, team);
    bvh__stream_fence();
}
#ifndef BVH_NO_THREADS
static void *bvh__worker_main(void *p) {
    bvh__worker *w = BVH__CAST(bvh__worker *, p);
    bvh__team *team = w->team;
    /* wait until the creator knows how many threads it got */
    pthread_mutex_lock(&team->mutex);
    while (!team->started) pthread_cond_wait(&team->cond, &team->mutex);
    pthread_mutex_unlock(&team->mutex);
    if (w->tid < team->n) bvh__team_fn_run(team, w->tid);
    return NULL;
}
#endif

/* Runs fn on up to `want` threads. Returns BVH_ERROR_OUT_OF_MEMORY only when the bookkeeping
   cannot be allocated; thread creation failures reduce the team instead. */
static bvh_result bvh__team_run(const bvh_allocator *al, uint32_t want, bvh__team_fn fn, void *arg) {
    bvh__team team;
    team.fn = fn;
    team.arg = arg;
    team.n = 1;
    team.pool = NULL;
#ifndef BVH_NO_THREADS
    if (want > 1) {
        uint32_t i, made = 0;
        pthread_t *th = BVH__ALLOC(al, pthread_t, want);
        bvh__worker *ws = BVH__ALLOC(al, bvh__worker, want);
        if (!th || !ws) {
            bvh__free(al, th);
            bvh__free(al, ws);
            return BVH_ERROR_OUT_OF_MEMORY;
        }
        pthread_mutex_init(&team.mutex, NULL);
        pthread_cond_init(&team.cond, NULL);
        team.waiting = team.generation = team.started = 0;
        team.n = want;
        for (i = 1; i < want; i++) {
            ws[i].team = &team;
            ws[i].tid = i;
            if (pthread_create(&th[i], NULL, bvh__worker_main, &ws[i]) != 0) break;
            made++;
        }
        pthread_mutex_lock(&team.mutex);
        team.n = made + 1; /* workers with tid >= n return at once */
        team.spin = team.n <= bvh__cpu_count() ? BVH__SPIN_ROUNDS : 0;
        team.started = 1;
        pthread_cond_broadcast(&team.cond);
        pthread_mutex_unlock(&team.mutex);
        bvh__team_fn_run(&team, 0);
        for (i = 1; i <= made; i++) pthread_join(th[i], NULL);
        pthread_cond_destroy(&team.cond);
        pthread_mutex_destroy(&team.mutex);
        bvh__free(al, th);
        bvh__free(al, ws);
        return BVH_SUCCESS;
    }
#else
    (void)want;
    (void)al;
#endif
    bvh__team_fn_run(&team, 0);
    return BVH_SUCCESS;
}
/* A caller's pool (bvh_thread_pool) in place of the team: thread tid of n becomes task tid. Its
   tasks may run one after another on one thread, so they must not meet: only phases without
   barriers (and without the team's mutex) run this way; `sync` marks a phase with barriers,
   which then runs on the calling thread alone, as a team of one (every phase gives the same
   result for any thread count). The phases that matter are cut at their barriers into steps,
   each its own run (bvh__ploc_steps, bvh__ploc_init_steps, bvh__run_runs). */
static void bvh__pool_task(void *arg, uint32_t index) {
    bvh__team *team = BVH__CAST(bvh__team *, arg);
    bvh__team_fn_run(team, index);
}
static bvh_result bvh__team_run_on(const bvh_thread_pool *pool, const bvh_allocator *al, uint32_t want, int sync,
                                   bvh__team_fn fn, void *arg) {
    bvh__team team;
    if (!pool || !pool->run) return bvh__team_run(al, want, fn, arg);
    team.fn = fn;
    team.arg = arg;
    team.pool = pool;
    team.n = sync || want < 1 ? 1 : want;
    if (team.n == 1)
        bvh__team_fn_run(&team, 0);
    else
        pool->run(pool->user, team.n, bvh__pool_task, &team);
    return BVH_SUCCESS;
}
/* Even split of [0, count) for thread tid of n. */
static void bvh__range(size_t count, uint32_t tid, uint32_t n, size_t *b, size_t *e) {
    *b = count * tid / n;
    *e = count * (tid + 1) / n;
}

/* ============================================================================================ */
/* == Morton codes and radix sort ================================================================ */
/* ============================================================================================ */
static uint64_t bvh__expand21(uint64_t v) { /* spreads 21 bits to every third bit */
    v &= 0x1fffff;
    v = (v | v << 32) & 0x1f00000000ffffULL;
    v = (v | v << 16) & 0x1f0000ff0000ffULL;
    v = (v | v << 8) & 0x100f00f00f00f00fULL;
    v = (v | v << 4) & 0x10c30c30c30c30c3ULL;
    v = (v | v << 2) & 0x1249249249249249ULL;
    return v;
}
/* 63-bit Morton code of p inside the centroid bounds (21 bits per axis). In double, so that
   bounds spanning more than FLT_MAX (e.g. -3e38 .. 3e38) still quantise; NaN clamps to 0. */
typedef struct bvh__mscale {
    double lo[3], scale[3];
} bvh__mscale;
static uint64_t bvh__morton(bvh_vec3 p, const bvh__mscale *m) {
    double f[3];
    uint64_t q[3];
    int a;
    f[0] = ((double)p.x - m->lo[0]) * m->scale[0];
    f[1] = ((double)p.y - m->lo[1]) * m->scale[1];
    f[2] = ((double)p.z - m->lo[2]) * m->scale[2];
    for (a = 0; a < 3; a++) {               /* written for maxsd/minsd and a signed 32-bit conversion */
        double x = f[a] > 0.0 ? f[a] : 0.0; /* NaN: 0 */
        x = x < 2097151.0 ? x : 2097151.0;
        q[a] = (uint64_t)(int32_t)x;
    }
    return bvh__expand21(q[0]) << 2 | bvh__expand21(q[1]) << 1 | bvh__expand21(q[2]);
}
static bvh__mscale bvh__morton_scale(bvh_aabb cb) {
    bvh__mscale m;
    double lo[3], hi[3];
    int a;
    lo[0] = cb.min.x;
    lo[1] = cb.min.y;
    lo[2] = cb.min.z;
    hi[0] = cb.max.x;
    hi[1] = cb.max.y;
    hi[2] = cb.max.z;
    for (a = 0; a < 3; a++) {
        double d = hi[a] - lo[a];
        m.lo[a] = lo[a];
        m.scale[a] = d > 0.0 ? 2097151.0 / d : 0.0;
    }
    return m;
}

/* LSD radix sort of (key, value) pairs, 11-bit digits, stable: equal keys keep value order.
   Passes whose digit is the same for every key are skipped. Parallel over the team: each thread
   histograms and scatters its own contiguous chunk, so the result is the same for any count. */
#define BVH__RADIX_BITS 11
#define BVH__RADIX_SIZE (1u << BVH__RADIX_BITS)
typedef struct bvh__sort {
    uint64_t *keys, *keys_tmp;
    uint32_t *vals, *vals_tmp;
    size_t n;
    uint32_t *hist; /* nthreads * BVH__RADIX_SIZE */
} bvh__sort;
/* The sort's steps, between which a team meets at barriers and a caller's pool ends a run
   (bvh__ploc_init_steps): each reads only what the steps before it wrote. */
/* Thread tid's histogram of the digit at `shift` over its pairs [b, e). */
static void bvh__radix_hist(bvh__sort *s, uint32_t tid, size_t b, size_t e, int shift) {
    uint32_t *h = s->hist + (size_t)tid * BVH__RADIX_SIZE;
    size_t i;
    memset(h, 0, BVH__RADIX_SIZE * sizeof(uint32_t));
    for (i = b; i < e; i++) h[(s->keys[i] >> shift) & (BVH__RADIX_SIZE - 1)]++;
}
/* From the histograms: whether one digit holds every key (the pass can be skipped). */
static int bvh__radix_one_digit(const bvh__sort *s, uint32_t nt) {
    uint32_t d, t;
    for (d = 0; d < BVH__RADIX_SIZE; d++) {
        size_t tot = 0;
        for (t = 0; t < nt; t++) tot += s->hist[(size_t)t * BVH__RADIX_SIZE + d];
        if (tot == s->n) return 1;
        if (tot != 0) return 0;
    }
    return 0;
}
/* From the histograms: whether a digit holds over a quarter of the keys (bvh__radix_sort_team). */
static int bvh__radix_big(const bvh__sort *s, uint32_t nt) {
    uint32_t d, t, big = 0;
    for (d = 0; d < BVH__RADIX_SIZE; d++) {
        size_t tot = 0;
        for (t = 0; t < nt; t++) tot += s->hist[(size_t)t * BVH__RADIX_SIZE + d];
        if (tot > s->n / 4) big = 1;
    }
    return (int)big;
}
/* The offsets of thread tid's pairs by digit, from the histograms: the offset of (digit d,
   thread tid) is the count of keys with a smaller digit plus those with digit d in earlier
   threads. */
static void bvh__radix_offsets(const bvh__sort *s, uint32_t tid, uint32_t nt, uint32_t local[BVH__RADIX_SIZE]) {
    uint32_t d, t;
    size_t sum = 0;
    for (d = 0; d < BVH__RADIX_SIZE; d++) {
        for (t = 0; t < nt; t++) {
            uint32_t c = s->hist[(size_t)t * BVH__RADIX_SIZE + d];
            if (t == tid) local[d] = (uint32_t)sum;
            sum += c;
        }
    }
}
/* One stable scatter of pairs [b, e) from keys/vals to keys_tmp/vals_tmp by the digit at shift. */
static void bvh__radix_move(bvh__sort *s, uint32_t local[BVH__RADIX_SIZE], int shift, size_t b, size_t e) {
    size_t i;
    for (i = b; i < e; i++) {
        uint64_t k = s->keys[i];
        uint32_t pos = local[(k >> shift) & (BVH__RADIX_SIZE - 1)]++;
        s->keys_tmp[pos] = k;
        s->vals_tmp[pos] = s->vals[i];
    }
}
static void bvh__radix_swap(bvh__sort *s) {
    uint64_t *tk = s->keys;
    uint32_t *tv = s->vals;
    s->keys = s->keys_tmp;
    s->vals = s->vals_tmp;
    s->keys_tmp = tk;
    s->vals_tmp = tv;
}
static void bvh__msd_local(uint64_t *ck, uint32_t *cv, uint64_t *ok, uint32_t *ov, size_t lo, size_t hi, int bits,
                           int into_other);
/* After the scatter by the top digit: the ranges of equal top digit that start in thread tid's
   [b, e), each sorted on its own in cache, from the scratch arrays back to keys/vals. */
static void bvh__radix_ranges(bvh__sort *s, uint32_t nt, size_t b, size_t e) {
    const int top = 64 - BVH__RADIX_BITS;
    uint32_t d, t;
    size_t sum = 0;
    for (d = 0; d < BVH__RADIX_SIZE; d++) {
        size_t start = sum;
        for (t = 0; t < nt; t++) sum += s->hist[(size_t)t * BVH__RADIX_SIZE + d];
        if (sum > start && start >= b && start < e)
            bvh__msd_local(s->keys_tmp, s->vals_tmp, s->keys, s->vals, start, sum, top, 1);
    }
}
/* One stable scatter of this thread's pairs [b, e) by the digit at `shift`, from the team's
   histograms (bvh__radix_offsets). */
static void bvh__radix_scatter(bvh__sort *s, uint32_t tid, uint32_t nt, bvh__team *team, int shift, size_t b,
                               size_t e) {
    uint32_t local[BVH__RADIX_SIZE];
    bvh__radix_offsets(s, tid, nt, local);
    bvh__team_sync(team); /* everyone has read the histograms */
    bvh__radix_move(s, local, shift, b, e);
}
/* LSD passes over all 64 bits (see bvh__radix_sort_team). */
static void bvh__radix_lsd_team(bvh__sort *s, uint32_t tid, uint32_t nt, bvh__team *team) {
    int shift;
    size_t b, e;
    bvh__range(s->n, tid, nt, &b, &e);
    for (shift = 0; shift < 64; shift += BVH__RADIX_BITS) {
        bvh__radix_hist(s, tid, b, e, shift);
        bvh__team_sync(team);
        /* every thread computes the same offsets; skip the pass if one digit holds everything */
        if (bvh__radix_one_digit(s, nt)) {
            bvh__team_sync(team);
            continue;
        }
        bvh__radix_scatter(s, tid, nt, team, shift, b, e);
        bvh__team_sync(team);
        if (tid == 0) bvh__radix_swap(s);
        bvh__team_sync(team);
    }
}

/* Sorts the pairs [lo, hi) of (ck, cv), whose keys agree above their low `bits` bits, stably by
   key; the result lands in (ok, ov) when `into_other`, else in (ck, cv). MSD, 4 to 8 bits a level,
   insertion sort from 16 pairs down: the range fits in cache, so no pass goes out to memory. */
#define BVH__MSD_SMALL 16
static void bvh__msd_local(uint64_t *ck, uint32_t *cv, uint64_t *ok, uint32_t *ov, size_t lo, size_t hi, int bits,
                           int into_other) {
    size_t m = hi - lo, i, j;
    while (bits > 0 && m > BVH__MSD_SMALL) {
        /* fewer buckets for fewer pairs, so that clearing and summing them does not dominate */
        const int want = m > 1024 ? 8 : m > 128 ? 6 : 4;
        uint32_t cnt[256], d, shift = (uint32_t)(bits > want ? bits - want : 0), width = (uint32_t)bits - shift;
        uint32_t mask = (1u << width) - 1, first = (uint32_t)((ck[lo] >> shift) & mask), nd = mask + 1;
        size_t off[257];
        memset(cnt, 0, nd * sizeof cnt[0]);
        for (i = lo; i < hi; i++) cnt[(ck[i] >> shift) & mask]++;
        if (cnt[first] == m) {
            bits = (int)shift;
            continue;
        } /* one digit: nothing to move */
        off[0] = lo;
        for (d = 0; d < nd; d++) off[d + 1] = off[d] + cnt[d];
        for (i = lo; i < hi; i++) {
            size_t at = off[(ck[i] >> shift) & mask]++;
            ok[at] = ck[i];
            ov[at] = cv[i];
        }
        /* the digit buckets now sit in (ok, ov), each ending at off[d] */
        for (d = 0, i = lo; d < nd; d++) {
            if (off[d] > i) bvh__msd_local(ok, ov, ck, cv, i, off[d], (int)shift, !into_other);
            i = off[d];
        }
        return;
    }
    /* equal high bits throughout, or a few pairs: insertion sort (stable), then move if asked */
    if (bits > 0)
        for (i = lo + 1; i < hi; i++) {
            uint64_t k = ck[i];
            uint32_t v = cv[i];
            for (j = i; j > lo && ck[j - 1] > k; j--) {
                ck[j] = ck[j - 1];
                cv[j] = cv[j - 1];
            }
            ck[j] = k;
            cv[j] = v;
        }
    if (into_other) {
        memcpy(ok + lo, ck + lo, m * sizeof *ok);
        memcpy(ov + lo, cv + lo, m * sizeof *ov);
    }
}
/* Called by every thread of a team; on return the sorted data is in keys/vals. Stable, so equal
   keys keep value order. One pass over memory scatters the pairs by their top 11 bits; each of
   those ranges is then sorted on its own in cache (bvh__msd_local), ranges split over the team by
   where they start. When one range would hold over a quarter of the pairs (clustered input) and
   there are several threads, LSD passes over all bits run instead, which split evenly. Either
   way the result is the one stable order, for any thread count. */
static void bvh__radix_sort_team(bvh__sort *s, uint32_t tid, uint32_t nt, bvh__team *team) {
    const int top = 64 - BVH__RADIX_BITS;
    size_t b, e;
    bvh__range(s->n, tid, nt, &b, &e);
    bvh__radix_hist(s, tid, b, e, top);
    bvh__team_sync(team);
    if (bvh__radix_big(s, nt) && nt > 1) {
        bvh__team_sync(team); /* everyone has read the histograms */
        bvh__radix_lsd_team(s, tid, nt, team);
        return;
    }
    bvh__radix_scatter(s, tid, nt, team, top, b, e);
    bvh__team_sync(team);
    bvh__radix_ranges(s, nt, b, e);
    bvh__team_sync(team);
}

/* ============================================================================================ */
/* == build context and output ================================================================== */
/* Every builder reads the context (primitive boxes and centroids in "local" order, the resolved
   options) and writes a bvh__out: nodes with the root at 0 and children adjacent, and references
   as local primitive ids. The front-end (bvh_build) maps them to the caller's indices. */
/* ============================================================================================ */
/* Progress and cancel (desc.progress). Reports come from the thread that called bvh_build
   alone: from the build's serial loops, and in team phases from thread 0, which is that thread.
   The build is cut into stages (front end, builder, back end, 8-wide copy), each a share
   [lo, hi] of [0, 1]; a report inside a stage says how far into it the build is, and the
   fractions passed on never go down. Once the callback has returned nonzero every later check
   returns nonzero, and the build unwinds through its error paths with BVH_ERROR_CANCELLED. */
typedef struct bvh__progress {
    int (*fn)(void *user, float fraction);
    void *user;
    float lo, hi, last;
    uint32_t work; /* units done in serial loops since the last report (bvh__tick) */
    int cancelled;
} bvh__progress;
/* Stages of a build, as fractions: the builder's own share is cut further by bvh__stage_in. */
#define BVH__STAGE_BUILD_LO 0.05f
#define BVH__STAGE_BUILD_HI 0.85f
#define BVH__STAGE_WIDE_LO 0.9f
#define BVH__PROGRESS_WORK 65536u /* serial loops report at least once per this many primitives */
static void bvh__stage(bvh__progress *g, float lo, float hi) {
    if (g) {
        g->lo = lo;
        g->hi = hi;
    }
}
/* [a, b] of the builder's share */
static void bvh__stage_in(bvh__progress *g, float a, float b) {
    const float w = BVH__STAGE_BUILD_HI - BVH__STAGE_BUILD_LO;
    bvh__stage(g, BVH__STAGE_BUILD_LO + w * a, BVH__STAGE_BUILD_LO + w * b);
}
/* Reports `done` (0..1) of the current stage; nonzero once the build is cancelled. */
static int bvh__report(bvh__progress *g, double done) {
    float f;
    if (!g || !g->fn) return 0;
    if (g->cancelled) return 1;
    done = done > 0.0 ? (done < 1.0 ? done : 1.0) : 0.0;
    f = g->lo + (float)((double)(g->hi - g->lo) * done);
    if (f < g->last) f = g->last;
    g->last = f;
    g->work = 0;
    if (g->fn(g->user, f)) g->cancelled = 1;
    return g->cancelled;
}
/* In a serial loop: `work` more primitives handled; reports when BVH__PROGRESS_WORK have passed. */
static int bvh__tick(bvh__progress *g, uint32_t work, double done) {
    if (!g || !g->fn) return 0;
    if (g->cancelled) return 1;
    g->work += work < BVH__PROGRESS_WORK ? work : BVH__PROGRESS_WORK;
    return g->work >= BVH__PROGRESS_WORK ? bvh__report(g, done) : 0;
}
static int bvh__cancelled(const bvh__progress *g) { return g && g->cancelled; }

typedef struct bvh__ctx {
    bvh_allocator al;
    const bvh_thread_pool *pool; /* the caller's pool, NULL: the team's threads */
    bvh__progress *prog;         /* never NULL during builds */
    uint32_t n;                  /* primitives taking part (n >= 1 inside builders) */
    bvh_aabb *boxes;             /* n boxes (PLOC releases them once its clusters hold them: NULL) */
    const bvh_triangles *tris;   /* the caller's triangles, NULL for box input */
    const bvh_aabb *in_boxes;    /* the caller's boxes, NULL for triangle input */
    const uint32_t *orig;        /* local id -> caller index when primitives were left out, else NULL */
    bvh_aabb bounds, cbounds;
    uint32_t max_leaf, threads, radius, sah_bins, ploc_top; /* sah_bins, ploc_top: 0 = off; else ploc_top >= 2 */
    uint32_t budget; /* collapse: tree bytes per primitive at most; 0 = no limit */
    float ci, cl, ct, split_budget;
    uint32_t opt_rounds, opt_threads; /* desc.optimize: 0 rounds = off; threads: desc.threads' */
    float opt_batch;
    int opt_done; /* the builder ran the optimizer before its own collapse */
} bvh__ctx;

typedef struct bvh__out {
    bvh_node *nodes;
    uint32_t node_count, node_cap;
    uint32_t *refs;
    uint32_t ref_count, ref_cap;
} bvh__out;

static void bvh__out_free(const bvh__ctx *c, bvh__out *o) {
    bvh__free(&c->al, o->nodes);
    bvh__free(&c->al, o->refs);
    memset(o, 0, sizeof *o);
}
static bvh_result bvh__out_init(const bvh__ctx *c, bvh__out *o, uint32_t node_cap, uint32_t ref_cap) {
    memset(o, 0, sizeof *o);
    o->nodes = BVH__ALLOC(&c->al, bvh_node, node_cap);
    o->refs = BVH__ALLOC(&c->al, uint32_t, ref_cap);
    if (!o->nodes || !o->refs) {
        bvh__out_free(c, o);
        return BVH_ERROR_OUT_OF_MEMORY;
    }
    o->node_cap = node_cap;
    o->ref_cap = ref_cap;
    return BVH_SUCCESS;
}

/* Runs a build phase on the context's pool or team (see bvh__team_run_on; sync: it has barriers). */
static bvh_result bvh__run(const bvh__ctx *c, uint32_t want, int sync, bvh__team_fn fn, void *arg) {
    return bvh__team_run_on(c->pool, &c->al, want, sync, fn, arg);
}

static const float *bvh__vertex(const bvh_triangles *t, uint32_t v);
BVH__INLINE void bvh__fetch_triangle(const bvh_triangles *t, uint32_t i, float out[9]);
/* Triangle of local primitive id, read from the caller's input (no copy is kept during builds). */
static void bvh__ctx_triangle(const bvh__ctx *c, uint32_t id, float out[9]) {
    bvh__fetch_triangle(c->tris, c->orig ? c->orig[id] : id, out);
}
/* Box of local primitive id: from the box array, or recomputed once it has been released. */
static bvh_aabb bvh__prim_box(const bvh__ctx *c, uint32_t id) {
    float t[9];
    if (c->boxes) return c->boxes[id];
    if (c->in_boxes) return c->in_boxes[c->orig ? c->orig[id] : id];
    bvh__ctx_triangle(c, id, t);
    return bvh__tri_box(t);
}
static bvh_vec3 bvh__prim_centroid(const bvh__ctx *c, uint32_t id) { return bvh__centroid(bvh__prim_box(c, id)); }

/* Sorts all primitives by the Morton code of their centroid; *out_ids gets the local ids in
   Morton order (ties in index order). Runs on the context's team if one is given. */
typedef struct bvh__morton_job {
    const bvh__ctx *c;
    bvh__sort sort;
    bvh__mscale ms;
} bvh__morton_job;
/* The Morton codes of thread tid's share of the primitives, their indices beside them. */
static void bvh__morton_codes_part(bvh__morton_job *j, uint32_t tid, uint32_t nt) {
    size_t b, e, i;
    bvh__range(j->c->n, tid, nt, &b, &e);
    for (i = b; i < e; i++) {
        bvh_vec3 p;
        if (j->c->boxes) { /* always, during builds; read in place */
            p = bvh__centroid(j->c->boxes[i]);
        } else {
            p = bvh__prim_centroid(j->c, (uint32_t)i);
        }
        j->sort.keys[i] = bvh__morton(p, &j->ms);
        j->sort.vals[i] = (uint32_t)i;
    }
}
static void bvh__morton_codes_team(bvh__morton_job *j, uint32_t tid, uint32_t nt, bvh__team *team) {
    bvh__morton_codes_part(j, tid, nt);
    bvh__team_sync(team);
    bvh__radix_sort_team(&j->sort, tid, nt, team);
}
static void bvh__morton_team_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    bvh__morton_codes_team(BVH__CAST(bvh__morton_job *, arg), tid, nt, team);
}
static bvh_result bvh__morton_job_init(const bvh__ctx *c, bvh__morton_job *j, uint32_t nthreads) {
    memset(j, 0, sizeof *j);
    j->c = c;
    j->sort.n = c->n;
    j->sort.keys = BVH__ALLOC(&c->al, uint64_t, c->n);
    j->sort.keys_tmp = BVH__ALLOC(&c->al, uint64_t, c->n);
    j->sort.vals = BVH__ALLOC(&c->al, uint32_t, c->n);
    j->sort.vals_tmp = BVH__ALLOC(&c->al, uint32_t, c->n);
    j->sort.hist = BVH__ALLOC(&c->al, uint32_t, (size_t)nthreads * BVH__RADIX_SIZE);
    j->ms = bvh__morton_scale(c->cbounds);
    if (!j->sort.keys || !j->sort.keys_tmp || !j->sort.vals || !j->sort.vals_tmp || !j->sort.hist)
        return BVH_ERROR_OUT_OF_MEMORY;
    return BVH_SUCCESS;
}
static void bvh__morton_job_free(const bvh__ctx *c, bvh__morton_job *j) {
    bvh__free(&c->al, j->sort.keys);
    bvh__free(&c->al, j->sort.keys_tmp);
    bvh__free(&c->al, j->sort.vals);
    bvh__free(&c->al, j->sort.vals_tmp);
    bvh__free(&c->al, j->sort.hist);
    memset(&j->sort, 0, sizeof j->sort);
}

/* ============================================================================================ */
/* == shared builder rules: object median, SAH leaf test, depth bound ============================ */
/* ============================================================================================ */
/* Key of an element for the selection: the centroid coordinate on `axis` of element e (a local
   primitive id, or a sah-midpoint reference), computed exactly as its builder computes centroids. */
typedef float (*bvh__key_fn)(const void *ctx, const void *e, int axis);

BVH__INLINE void bvh__swap_bytes(unsigned char *x, unsigned char *y, size_t size) {
    unsigned char t[32]; /* the largest element selected (a sah-midpoint reference) fits */
    BVH_ASSERT(size <= sizeof t);
    memcpy(t, x, size);
    memcpy(x, y, size);
    memcpy(y, t, size);
}
/* Quickselect (Hoare 1961, "Algorithm 65: Find") with a median-of-three pivot and Hoare's
   partition, which splits runs of equal keys evenly. Rearranges the n elements of `size` bytes
   at v so that element k has the k-th smallest key, no larger key before it, no smaller after.
   Inlined into each caller, so the key function is a direct call. */
BVH__INLINE void bvh__select(void *v, size_t size, uint32_t n, uint32_t k, bvh__key_fn key, const void *ctx, int axis) {
    unsigned char *e = BVH__CAST(unsigned char *, v);
    uint32_t lo = 0, hi = n - 1;
    while (hi > lo) {
        uint32_t i = lo, j = hi, mid = lo + (hi - lo) / 2;
        float a = key(ctx, e + (size_t)lo * size, axis);
        float b = key(ctx, e + (size_t)mid * size, axis);
        float d = key(ctx, e + (size_t)hi * size, axis);
        float pivot = a < b ? (b < d ? b : (a < d ? d : a)) : (a < d ? a : (b < d ? d : b));
        for (;;) {
            while (key(ctx, e + (size_t)i * size, axis) < pivot) i++;
            while (key(ctx, e + (size_t)j * size, axis) > pivot) j--;
            if (i >= j) break;
            bvh__swap_bytes(e + (size_t)i * size, e + (size_t)j * size, size);
            i++;
            j--;
        }
        /* now [lo, j] <= pivot <= [j+1, hi] (when i > j) or element i == pivot (i == j) */
        if (i == j) {
            if (k == i) return;
            if (k < i)
                hi = i - 1;
            else
                lo = i + 1;
        } else if (k <= j) {
            hi = j;
        } else {
            lo = j + 1;
        }
    }
}
/* The axis an object median splits: the longest of the centroid bounds cb (ties to the lower
   axis), or -1 when all centroids are equal and any split in half is as good. */
static int bvh__median_axis(bvh_aabb cb) {
    float ex = cb.max.x - cb.min.x;
    float ey = cb.max.y - cb.min.y;
    float ez = cb.max.z - cb.min.z;
    if (!(ex > 0.0f || ey > 0.0f || ez > 0.0f)) return -1;
    return ex >= ey && ex >= ez ? 0 : ey >= ez ? 1 : 2;
}

/* SAH cost of a leaf of n primitives whose box has half area a: E_t = a (C_l + C_t n) (Wald 2007),
   computed in the type of a and n (float where the cost is stored per node, double where it is
   compared with a sum over many boxes). */
#define BVH__LEAF_COST(c, a, n) ((a) * ((c)->cl + (c)->ct * (n)))
/* The SAH leaf-vs-split rule of every builder that asks it: a node of n primitives becomes a
   leaf when a leaf may hold them and costs no more than splitting it (ties: the leaf, which
   saves nodes). Float costs convert to double exactly, so the comparison is the same. */
static int bvh__sah_leaf(const bvh__ctx *c, uint32_t n, double leaf_cost, double split_cost) {
    return n <= c->max_leaf && leaf_cost <= split_cost;
}
/* The depth bound: a subtree whose root is at level `level` (the tree's root is level 1) and
   that has `below` levels under its root keeps the tree within BVH_MAX_DEPTH levels. */
static int bvh__fits_depth(uint32_t level, uint32_t below) { return level + below <= BVH_MAX_DEPTH; }

/* ============================================================================================ */
/* == object-median top-down (the study's baseline top-down builder) ============================= */
/* Splits the longest axis of the node's centroid bounds at the object median (quickselect, O(n)
   per level, so O(n log n) in all), leaf at max_leaf primitives or fewer. Also used to rebuild
   any subtree of another builder that would exceed BVH_MAX_DEPTH: its depth is ceil(log2(n)). */
/* ============================================================================================ */
static float bvh__id_key(const void *ctx, const void *e, int axis) {
    const bvh__ctx *c = BVH__CAST(const bvh__ctx *, ctx);
    uint32_t id;
    memcpy(&id, e, sizeof id);
    return bvh__get(bvh__prim_centroid(c, id), axis);
}

/* Builds a median tree over o->refs[first .. first+count) with its root in node `root`. */
/* A cancelled build (c->prog) stops it early, the tree unfinished. */
static void bvh__median_build(const bvh__ctx *c, bvh__out *o, uint32_t root, uint32_t first, uint32_t count) {
    uint32_t stack[3 * 40]; /* the median tree is at most ceil(log2(2^30)) + 1 deep */
    uint32_t sp = 0;
    double work = 0.0, total = (double)count * (1.0 + log2((double)count / (double)c->max_leaf + 1.0));
    stack[sp++] = root;
    stack[sp++] = first;
    stack[sp++] = count;
    while (sp) {
        uint32_t m = stack[--sp], b = stack[--sp], ni = stack[--sp], i, half;
        bvh_node *node = &o->nodes[ni];
        bvh_aabb box = bvh__empty(), cb = bvh__empty();
        int axis;
        work += m;
        if (bvh__tick(c->prog, m, work / total)) return;
        for (i = b; i < b + m; i++) {
            uint32_t id = o->refs[i];
            bvh_aabb pb = bvh__prim_box(c, id);
            box = bvh__merge(box, pb);
            bvh__grow(&cb, bvh__centroid(pb));
        }
        bvh__set_box(node, box);
        if (m <= c->max_leaf) {
            node->index = b;
            node->count = m;
            continue;
        }
        axis = bvh__median_axis(cb);
        half = m / 2;
        if (axis >= 0) bvh__select(o->refs + b, sizeof *o->refs, m, half, bvh__id_key, c, axis);
        node->index = o->node_count;
        node->count = 0;
        o->node_count += 2;
        stack[sp++] = node->index + 1;
        stack[sp++] = b + half;
        stack[sp++] = m - half;
        stack[sp++] = node->index;
        stack[sp++] = b;
        stack[sp++] = half;
    }
}

static bvh_result bvh__build_top_down(const bvh__ctx *c, bvh__out *o) {
    uint32_t i;
    bvh_result r = bvh__out_init(c, o, 2 * c->n - 1, c->n);
    if (r != BVH_SUCCESS) return r;
    for (i = 0; i < c->n; i++) o->refs[i] = i;
    o->ref_count = c->n;
    o->node_count = 1;
    bvh__median_build(c, o, 0, 0, c->n);
    return bvh__cancelled(c->prog) ? BVH_ERROR_CANCELLED : BVH_SUCCESS;
}

/* ============================================================================================ */
/* == tree post-processing: depth-first emission, SAH collapse, depth bound ====================== */
/* Bottom-up builders produce a "source" tree: nodes whose children are adjacent and always stored
   before their parent, the root last, leaves indexing a `map` of local ids. bvh__emit writes it
   to a bvh__out in depth-first order (root at 0, left subtree right after its parent), optionally
   collapsing subtrees into leaves where the SAH says a leaf is cheaper (Meister & Bittner 2018,
   Sec. 4.3; their reference code collapses the same way), and rebuilds with the median builder any
   subtree that would make the tree deeper than BVH_MAX_DEPTH. */
/* ============================================================================================ */
#define BVH__COLLAPSE_BIT 0x80000000u
/* The PLOC builders' collapse, when desc.costs is zero, costs an interior node 2.5 triangle
   tests instead of 1: subtrees of a few triangles become leaves, which the 8-wide layout tests
   as one packet anyway, so the binary tree has about half the nodes (bytes, layout, refit and
   load in proportion) for a few percent of SAH and no measurable trace speed (docs/DESIGN.md). */
#ifndef BVH__PLOC_INTERIOR
#define BVH__PLOC_INTERIOR 2.5f
#endif
#define BVH__EMIT_TASKS 64
/* A subtree to write: source node si goes to output node di; its descendants' nodes start at
   `node` and its references at `ref`. Positions follow from the subtree sizes: a
   node's children pair comes first, then the left subtree's nodes, then the right's; so does the
   order of references. Any split into tasks writes the same output. */
typedef struct bvh__emit_task {
    uint32_t si, di, node, ref;
} bvh__emit_task;
typedef struct bvh__emit_job {
    const bvh_node *src;
    const uint32_t *map, *cnt, *size;
    bvh__out *o;
    const bvh__emit_task *tasks;
    const uint32_t *owner; /* task -> thread */
    uint32_t task_count;
} bvh__emit_job;
/* Writes the references of every primitive below source node si to refs, left to right, with
   `stack` as scratch (room for the subtree's height + 1 entries); returns how many. */
static uint32_t bvh__gather_refs(const bvh_node *src, const uint32_t *map, uint32_t si, uint32_t *stack,
                                 uint32_t *refs) {
    uint32_t sp = 0, n = 0;
    stack[sp++] = si;
    while (sp) {
        const bvh_node *x = &src[stack[--sp]];
        if (x->count) {
            uint32_t k;
            for (k = 0; k < x->count; k++) refs[n++] = map[x->index + k];
        } else {
            stack[sp++] = x->index + 1;
            stack[sp++] = x->index;
        }
    }
    return n;
}
/* Writes one subtree (no depth rebuild: used only when the tree is shallow enough). */
static void bvh__emit_subtree(const bvh__emit_job *j, bvh__emit_task t0) {
    bvh__emit_task stack[BVH_MAX_DEPTH + 2];
    uint32_t sp = 0, small[2 * BVH__MAX_LEAF + 8];
    stack[sp++] = t0;
    while (sp) {
        bvh__emit_task t = stack[--sp];
        const bvh_node *s = &j->src[t.si];
        bvh_node *d = &j->o->nodes[t.di];
        d->min = s->min;
        d->max = s->max;
        if (s->count || (j->cnt[t.si] & BVH__COLLAPSE_BIT)) { /* a leaf: gather the primitives below */
            d->index = t.ref;
            d->count = bvh__gather_refs(j->src, j->map, t.si, small, j->o->refs + t.ref);
        } else {
            uint32_t l = s->index, lsize = j->size[l], lcnt = j->cnt[l] & ~BVH__COLLAPSE_BIT;
            bvh__emit_task a, b;
            d->index = t.node;
            d->count = 0;
            a.si = l;
            a.di = t.node;
            a.node = t.node + 2;
            a.ref = t.ref;
            b.si = l + 1;
            b.di = t.node + 1;
            b.node = t.node + 1 + lsize;
            b.ref = t.ref + lcnt;
            stack[sp++] = b;
            stack[sp++] = a;
        }
    }
}
static void bvh__emit_team_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    const bvh__emit_job *j = BVH__CAST(const bvh__emit_job *, arg);
    uint32_t i;
    (void)team;
    for (i = 0; i < j->task_count; i++)
        if (j->owner[i] % nt == tid) bvh__emit_subtree(j, j->tasks[i]);
}

/* Pass 1 of bvh__emit, bottom-up over src (children before parents): primitives, output size,
   height and SAH cost of every subtree, and the collapse decisions. With `blocks` (the ends of
   runs of src whose children all lie in earlier runs, as each PLOC iteration appends), each run
   is split over the team, which meets at a barrier between runs; without, all of src is one run
   on one thread. */
typedef union bvh__fu {
    float f;
    uint32_t u;
} bvh__fu; /* pass 1: SAH cost; pass 2: see bvh__place */
typedef struct bvh__sizes {
    const bvh__ctx *c;
    const bvh_node *src;
    uint32_t *cnt, *size;
    uint8_t *height;
    bvh__fu *cost;
    const uint32_t *blocks;
    uint32_t block_count;
} bvh__sizes;
static void bvh__sizes_node(const bvh__sizes *q, uint32_t i) {
    const bvh__ctx *c = q->c;
    const bvh_node *s = &q->src[i];
    uint32_t *cnt = q->cnt, *size = q->size;
    uint8_t *height = q->height;
    bvh__fu *cost = q->cost;
    if (s->count) {
        cnt[i] = s->count;
        height[i] = 0;
        size[i] = 1;
        if (cost) cost[i].f = BVH__LEAF_COST(c, bvh__half_area(bvh__node_box(s)), (float)s->count);
    } else {
        uint32_t l = s->index, n = (cnt[l] & ~BVH__COLLAPSE_BIT) + (cnt[l + 1] & ~BVH__COLLAPSE_BIT);
        uint32_t h = height[l] > height[l + 1] ? height[l] : height[l + 1];
        cnt[i] = n;
        height[i] = (uint8_t)(h >= 255 ? 255 : h + 1);
        size[i] = 1 + size[l] + size[l + 1];
        if (cost) {
            float a = bvh__half_area(bvh__node_box(s));
            float split = c->ci * a + cost[l].f + cost[l + 1].f;
            float leaf = BVH__LEAF_COST(c, a, (float)n);
            if (bvh__sah_leaf(c, n, leaf, split)) {
                cost[i].f = leaf;
                cnt[i] |= BVH__COLLAPSE_BIT;
                height[i] = 0;
                size[i] = 1;
            } else
                cost[i].f = split;
        }
    }
}
/* Prefetch distances of the loops that read or write at random (in elements, or pairs for place). */
#define BVH__SIZES_AHEAD 16
#define BVH__PLACE_AHEAD 8
#define BVH__GATHER_AHEAD 24
/* Phases made of runs that are done in order, the items of a run independent of each other and
   split over the threads (bvh__sizes, bvh__place): a team meets at a barrier after each run; a
   caller's pool, whose tasks must not meet, gets a run of its own for each run of at least
   BVH__POOL_RUN_MIN items, and the calling thread does the smaller ones alone (a pool run costs
   about as much as such a run's work). The split never changes a result. */
#define BVH__POOL_RUN_MIN 4096u
typedef struct bvh__runs {
    void (*run)(const void *arg, uint32_t k, uint32_t tid, uint32_t nt); /* thread tid's share of run k */
    uint32_t (*items)(const void *arg, uint32_t k);                      /* run k's item count */
    const void *arg;
    uint32_t count, k; /* runs 0 .. count - 1; k: the one a pool's tasks do */
} bvh__runs;
static void bvh__runs_team_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    const bvh__runs *x = BVH__CAST(const bvh__runs *, arg);
    uint32_t k;
    for (k = 0; k < x->count; k++) {
        x->run(x->arg, k, tid, nt);
        bvh__team_sync(team);
    }
}
static void bvh__runs_task_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    const bvh__runs *x = BVH__CAST(const bvh__runs *, arg);
    (void)team;
    x->run(x->arg, x->k, tid, nt);
}
static bvh_result bvh__run_runs(const bvh__ctx *c, uint32_t nt, bvh__runs *x) {
    bvh_result r;
    if (!c->pool || nt <= 1) return bvh__run(c, nt, 1, bvh__runs_team_fn, x);
    for (x->k = 0; x->k < x->count; x->k++) {
        if (x->items(x->arg, x->k) < BVH__POOL_RUN_MIN)
            x->run(x->arg, x->k, 0, 1);
        else if ((r = bvh__run(c, nt, 0, bvh__runs_task_fn, x)) != BVH_SUCCESS)
            return r;
    }
    return BVH_SUCCESS;
}

/* Pass 1's run k (src[blocks[k - 1] .. blocks[k])), thread tid's share. */
static void bvh__sizes_run(const void *arg, uint32_t k, uint32_t tid, uint32_t nt) {
    const bvh__sizes *q = BVH__CAST(const bvh__sizes *, arg);
    const uint32_t start = k ? q->blocks[k - 1] : 0;
    size_t b, e, i;
    bvh__range(q->blocks[k] - start, tid, nt, &b, &e);
    for (i = b; i < e; i++) {
        /* a node's children lie anywhere in earlier runs: ask for theirs a few nodes ahead */
        if (i + BVH__SIZES_AHEAD < e) {
            const bvh_node *s = &q->src[start + i + BVH__SIZES_AHEAD];
            if (!s->count) {
                BVH__PREFETCH(&q->cnt[s->index]);
                BVH__PREFETCH(&q->size[s->index]);
                BVH__PREFETCH(&q->height[s->index]);
                if (q->cost) BVH__PREFETCH(&q->cost[s->index]);
            }
        }
        bvh__sizes_node(q, start + (uint32_t)i);
    }
}
static uint32_t bvh__sizes_items(const void *arg, uint32_t k) {
    const bvh__sizes *q = BVH__CAST(const bvh__sizes *, arg);
    return q->blocks[k] - (k ? q->blocks[k - 1] : 0);
}
/* Pass 1 over every run, on nt threads. */
static bvh_result bvh__sizes_go(const bvh__ctx *c, uint32_t nt, const bvh__sizes *q) {
    bvh__runs x;
    x.run = bvh__sizes_run;
    x.items = bvh__sizes_items;
    x.arg = q;
    x.count = q->block_count;
    x.k = 0;
    return bvh__run_runs(c, nt, &x);
}

/* The memory budget (desc.ploc.max_bytes_per_prim) as output nodes, for a tree of `prims` references. */
static uint64_t bvh__budget_nodes(const bvh__ctx *c, uint32_t prims) {
    uint64_t bytes = (uint64_t)c->budget * prims, idx = (uint64_t)prims * sizeof(uint32_t);
    return bytes > idx ? (bytes - idx) / sizeof(bvh_node) : 0;
}
#define BVH__BUDGET_STEPS 8
/* Pass 1 gave a tree over the budget: it is redone with a dearer interior node, which turns the
   subtrees where a leaf costs least extra into leaves first (a Lagrange multiplier on the node
   count). The cost is doubled until the tree fits, then narrowed by interpolation between the
   last cost over and the last that fits (node counts against costs, both on log scales) until
   the tree is within 1% of the budget or BVH__BUDGET_STEPS tries; the tree kept is the one of the
   lowest cost found to fit, so it always fits if any does. If even an unbounded cost (every
   subtree of max_leaf primitives or fewer a leaf) does not fit, that smallest tree is kept. Each
   try is one more pass 1, O(n). */
static bvh_result bvh__fit_budget(const bvh__ctx *c, bvh__sizes *q, uint32_t nthreads) {
    bvh__ctx cc = *c;
    uint32_t root = q->blocks[q->block_count - 1] - 1, k;
    uint64_t limit = bvh__budget_nodes(c, q->cnt[root] & ~BVH__COLLAPSE_BIT);
    double lo = c->ci > 0.0f ? c->ci : 1.0, hi = 2.0 * lo, top = 1e6 * lo, nlo = q->size[root], nhi;
    int held = 1; /* the arrays hold the tree of cost hi */
    bvh_result r;
    q->c = &cc;
    for (;;) { /* double until it fits */
        cc.ci = (float)hi;
        if ((r = bvh__sizes_go(c, nthreads, q)) != BVH_SUCCESS) return r;
        if (bvh__report(c->prog, 0.0)) return BVH_ERROR_CANCELLED;
        nhi = q->size[root];
        if (nhi <= (double)limit) break;
        if (hi > top) {      /* the smallest tree the leaf size allows */
            cc.ci = 3.0e38f; /* finite: a zero area times it stays zero */
            return bvh__sizes_go(c, nthreads, q);
        }
        lo = hi;
        nlo = nhi;
        hi *= 2.0;
    }
    for (k = 0; k < BVH__BUDGET_STEPS && nhi < 0.99 * (double)limit; k++) {
        double aim = 0.995 * (double)limit, f = (log(nlo) - log(aim)) / (log(nlo) - log(nhi > 1.0 ? nhi : 1.0));
        double mid = lo * pow(hi / lo, f < 0.1 ? 0.1 : f > 0.9 ? 0.9 : f), n;
        cc.ci = (float)mid;
        if ((r = bvh__sizes_go(c, nthreads, q)) != BVH_SUCCESS) return r;
        if (bvh__report(c->prog, 0.0)) return BVH_ERROR_CANCELLED;
        n = q->size[root];
        if (n > (double)limit) {
            lo = mid;
            nlo = n;
            held = 0;
        } else {
            hi = mid;
            nhi = n;
            held = 1;
        }
    }
    if (held) return BVH_SUCCESS;
    cc.ci = (float)hi;
    return bvh__sizes_go(c, nthreads, q);
}

/* Pass 2 of bvh__emit with `blocks`, when no subtree is rebuilt: src is walked from the root down,
   run by run from the last (parents before children), each run's pairs split over the team. A
   children pair (l, l + 1) gets from its parent, in pos[l], the output index of its first node
   and, in pos[l + 1], its first reference; pos[l] = 0 marks a pair inside a collapsed leaf, whose
   primitives are still written at their places. Positions follow from the sizes exactly as in the
   depth-first walk (bvh__emit_subtree), so the tree is the same; but every read of src, cnt, size
   and pos goes forward through memory, where the walk jumped about. */
typedef struct bvh__place {
    const bvh_node *src;
    const uint32_t *map, *cnt, *size, *blocks;
    bvh__fu *pos;
    bvh__out *o;
    uint32_t block_count;
} bvh__place;
/* Source node x goes to output node di (0: inside a leaf), its children pair to `node`, its
   references start at ref. */
static void bvh__place_node(const bvh__place *q, uint32_t x, uint32_t di, uint32_t node, uint32_t ref) {
    const bvh_node *s = &q->src[x];
    bvh_node *d = &q->o->nodes[di];
    uint32_t k, leaf = s->count || (q->cnt[x] & BVH__COLLAPSE_BIT);
    if (s->count)
        for (k = 0; k < s->count; k++) q->o->refs[ref + k] = q->map[s->index + k];
    else {
        q->pos[s->index].u = leaf || !di ? 0 : node;
        q->pos[s->index + 1].u = ref;
    }
    if (!di) return;
    d->min = s->min;
    d->max = s->max;
    if (leaf) {
        d->index = ref;
        d->count = q->cnt[x] & ~BVH__COLLAPSE_BIT;
    } else {
        d->index = node;
        d->count = 0;
    }
}
/* Pass 2's run r: src's run k = block_count - 2 - r (from the last below the root's, down to
   the first), thread tid's share of its pairs. */
static void bvh__place_run(const void *arg, uint32_t r, uint32_t tid, uint32_t nt) {
    const bvh__place *q = BVH__CAST(const bvh__place *, arg);
    const uint32_t k = q->block_count - 2 - r, start = k ? q->blocks[k - 1] : 0;
    size_t b, e, i;
    {
        bvh__range((q->blocks[k] - start) / 2, tid, nt, &b, &e);
        for (i = b; i < e; i++) {
            uint32_t l = start + 2 * (uint32_t)i, di = q->pos[l].u, ref = q->pos[l + 1].u;
            uint32_t lcnt = q->cnt[l] & ~BVH__COLLAPSE_BIT;
            if (i + BVH__PLACE_AHEAD < e) { /* the output nodes and the children's pos lie anywhere */
                const bvh_node *a = &q->src[l + 2 * BVH__PLACE_AHEAD];
                BVH__PREFETCH(&q->o->nodes[q->pos[l + 2 * BVH__PLACE_AHEAD].u]);
                if (!a[0].count) BVH__PREFETCH(&q->pos[a[0].index]);
                if (!a[1].count) BVH__PREFETCH(&q->pos[a[1].index]);
            }
            bvh__place_node(q, l, di, di + 2, ref);
            bvh__place_node(q, l + 1, di ? di + 1 : 0, di + 1 + q->size[l], ref + lcnt);
        }
    }
}
static uint32_t bvh__place_items(const void *arg, uint32_t r) {
    const bvh__place *q = BVH__CAST(const bvh__place *, arg);
    const uint32_t k = q->block_count - 2 - r;
    return (q->blocks[k] - (k ? q->blocks[k - 1] : 0)) / 2;
}

/* Pass 2 with PLOC's runs (bvh__place): the root is written here, the runs below it by the team. */
static bvh_result bvh__emit_placed(const bvh__ctx *c, const bvh__sizes *q, const uint32_t *map, uint32_t src_count,
                                   uint32_t nthreads, bvh__out *o) {
    bvh__place pl;
    const bvh_node *root = &q->src[src_count - 1];
    bvh_node *d = &o->nodes[0];
    d->min = root->min;
    d->max = root->max;
    d->index = 1;
    d->count = 0;
    q->cost[root->index].u = 1; /* the pass 1 costs' array becomes the positions */
    q->cost[root->index + 1].u = 0;
    pl.src = q->src;
    pl.map = map;
    pl.cnt = q->cnt;
    pl.size = q->size;
    pl.blocks = q->blocks;
    pl.pos = q->cost;
    pl.o = o;
    pl.block_count = q->block_count;
    {
        bvh__runs x;
        x.run = bvh__place_run;
        x.items = bvh__place_items;
        x.arg = &pl;
        x.count = q->block_count - 1; /* the runs below the root's (block_count >= 1) */
        x.k = 0;
        return bvh__run_runs(c, nthreads, &x);
    }
}

/* Pass 2 when no subtree is rebuilt: positions follow from the sizes, so the subtrees can be
   written by the team. With several threads, the largest subtree is split until there are
   BVH__EMIT_TASKS of them or the largest has under 4096 nodes (half of
   BVH__MIN_PRIMS_PER_THREAD, which the tests lower to split small trees too); the top nodes are
   written here, each subtree goes to the least loaded thread so far. The output is the same for
   any thread count. */
static bvh_result bvh__emit_tasks(const bvh__ctx *c, const bvh__sizes *q, const uint32_t *map, uint32_t src_count,
                                  uint32_t nthreads, bvh__out *o) {
    const bvh_node *src = q->src;
    const uint32_t *cnt = q->cnt, *size = q->size;
    bvh__emit_task tasks[BVH__EMIT_TASKS];
    uint32_t owner[BVH__EMIT_TASKS], load[BVH__EMIT_TASKS], nt = nthreads, k, t;
    bvh__emit_job job;
    uint32_t ntasks = 1;
    tasks[0].si = src_count - 1;
    tasks[0].di = 0;
    tasks[0].node = 1;
    tasks[0].ref = 0;
    if (nt > BVH__EMIT_TASKS / 4) nt = BVH__EMIT_TASKS / 4;
    while (nt > 1 && ntasks + 1 < BVH__EMIT_TASKS) {
        /* expand the largest task that is an interior node in the output */
        uint32_t big = ntasks, bigsize = 0;
        for (k = 0; k < ntasks; k++) {
            const bvh_node *s = &src[tasks[k].si];
            if (!s->count && !(cnt[tasks[k].si] & BVH__COLLAPSE_BIT) && size[tasks[k].si] > bigsize) {
                big = k;
                bigsize = size[tasks[k].si];
            }
        }
        if (big == ntasks || 2 * (size_t)bigsize < BVH__MIN_PRIMS_PER_THREAD) break;
        {
            bvh__emit_task x = tasks[big];
            const bvh_node *s = &src[x.si];
            bvh_node *d = &o->nodes[x.di];
            uint32_t l = s->index;
            d->min = s->min;
            d->max = s->max;
            d->index = x.node;
            d->count = 0;
            tasks[big].si = l;
            tasks[big].di = x.node;
            tasks[big].node = x.node + 2;
            tasks[big].ref = x.ref;
            tasks[ntasks].si = l + 1;
            tasks[ntasks].di = x.node + 1;
            tasks[ntasks].node = x.node + 1 + size[l];
            tasks[ntasks].ref = x.ref + (cnt[l] & ~BVH__COLLAPSE_BIT);
            ntasks++;
        }
    }
    for (t = 0; t < nt; t++) load[t] = 0;
    for (k = 0; k < ntasks; k++) { /* greedy: each task to the least loaded thread so far */
        uint32_t least = 0;
        for (t = 1; t < nt; t++)
            if (load[t] < load[least]) least = t;
        owner[k] = least;
        load[least] += size[tasks[k].si];
    }
    job.src = src;
    job.map = map;
    job.cnt = cnt;
    job.size = size;
    job.o = o;
    job.tasks = tasks;
    job.owner = owner;
    job.task_count = ntasks;
    return bvh__run(c, nt, 0, bvh__emit_team_fn, &job);
}

/* Pass 2 when the tree is too deep: one thread walks from the root and rebuilds with the median
   builder every subtree that would cross the depth bound. Node positions then depend on the
   rebuilt subtrees, so the nodes are appended as they come (still depth-first, children
   adjacent). */
static bvh_result bvh__emit_rebuild(const bvh__ctx *c, const bvh__sizes *q, const uint32_t *map, uint32_t src_count,
                                    bvh__out *o) {
    const bvh_node *src = q->src;
    const uint32_t *cnt = q->cnt;
    const uint8_t *height = q->height;
    uint32_t stack[3 * (BVH_MAX_DEPTH + 2)], small[2 * BVH__MAX_LEAF + 8], *gather = NULL, sp = 0;
    bvh_result r = BVH_SUCCESS;
    o->node_count = 1;
    stack[sp++] = src_count - 1;
    stack[sp++] = 0;
    stack[sp++] = 1;
    while (sp) {
        uint32_t level = stack[--sp], di = stack[--sp], si = stack[--sp];
        const bvh_node *s = &src[si];
        bvh_node *d = &o->nodes[di];
        int flatten = s->count || (cnt[si] & BVH__COLLAPSE_BIT);
        /* rebuilt only in the upper half of the bound, where a median tree (ceil(log2 n) + 1 levels
           for n <= 2^30 primitives) always fits */
        int too_deep = !flatten && level <= BVH_MAX_DEPTH / 2 && !bvh__fits_depth(level, height[si]);
        if (flatten || too_deep) {
            /* gather every primitive below si: a small subtree, or (rarely) a too deep one */
            uint32_t first = o->ref_count, n = cnt[si] & ~BVH__COLLAPSE_BIT, *g = small;
            if (too_deep) {
                if (!gather && !(gather = BVH__ALLOC(&c->al, uint32_t, src_count))) {
                    r = BVH_ERROR_OUT_OF_MEMORY;
                    break;
                }
                g = gather;
            }
            o->ref_count += bvh__gather_refs(src, map, si, g, o->refs + first);
            if (too_deep) {
                bvh__median_build(c, o, di, first, n);
                continue;
            }
            d->min = s->min;
            d->max = s->max;
            d->index = first;
            d->count = n;
            continue;
        }
        d->min = s->min;
        d->max = s->max;
        d->count = 0;
        d->index = o->node_count;
        o->node_count += 2;
        stack[sp++] = s->index + 1;
        stack[sp++] = d->index + 1;
        stack[sp++] = level + 1;
        stack[sp++] = s->index;
        stack[sp++] = d->index;
        stack[sp++] = level + 1;
    }
    bvh__free(&c->al, gather);
    return r;
}

/* Writes the source tree to o: pass 1 (bvh__sizes_go, and bvh__fit_budget over the memory
   budget) sizes every subtree and makes the collapse decisions; pass 2 writes the nodes, by the
   first of these that applies: PLOC's runs from the root down (bvh__emit_placed), subtrees in
   parallel where no subtree crosses the depth bound (bvh__emit_tasks), else one walk that
   rebuilds the subtrees that cross it (bvh__emit_rebuild). */
static bvh_result bvh__emit(const bvh__ctx *c, const bvh_node *src, uint32_t src_count, const uint32_t *map,
                            int collapse, uint32_t nthreads, const uint32_t *blocks, uint32_t block_count,
                            bvh__out *o) {
    uint32_t *cnt = BVH__ALLOC(&c->al, uint32_t, src_count);  /* prims below; top bit: collapsed */
    uint32_t *size = BVH__ALLOC(&c->al, uint32_t, src_count); /* output nodes below, itself included */
    uint8_t *height = BVH__ALLOC(&c->al, uint8_t, src_count); /* after collapsing, capped at 255 */
    /* with blocks, the costs' array is also pass 2's pos (bvh__place) */
    bvh__fu *cost = collapse || blocks ? BVH__ALLOC(&c->al, bvh__fu, src_count) : NULL;
    const uint32_t root = src_count - 1;
    uint32_t prims;
    int shallow;
    bvh__sizes q;
    bvh_result r = BVH_SUCCESS;
    if (!cnt || !size || !height || ((collapse || blocks) && !cost)) {
        r = BVH_ERROR_OUT_OF_MEMORY;
        goto done;
    }
    q.c = c;
    q.src = src;
    q.cnt = cnt;
    q.size = size;
    q.height = height;
    q.cost = collapse ? cost : NULL;
    q.blocks = blocks ? blocks : &src_count;
    q.block_count = blocks ? block_count : 1;
    r = bvh__sizes_go(c, blocks ? nthreads : 1, &q);
    if (r == BVH_SUCCESS && bvh__report(c->prog, 0.0)) r = BVH_ERROR_CANCELLED;
    if (r == BVH_SUCCESS && collapse && c->budget && size[root] > bvh__budget_nodes(c, cnt[root] & ~BVH__COLLAPSE_BIT))
        r = bvh__fit_budget(c, &q, blocks ? nthreads : 1);
    if (r != BVH_SUCCESS) goto done;
    q.c = c; /* bvh__fit_budget pointed it at its own copy */
    q.cost = cost;
    prims = cnt[root] & ~BVH__COLLAPSE_BIT;
    shallow = bvh__fits_depth(1, height[root]);
    /* exact size unless a subtree must be rebuilt for depth (then at most 2 n - 1 nodes) */
    r = bvh__out_init(c, o, shallow ? size[root] : 2 * prims - 1, prims);
    if (r != BVH_SUCCESS) goto done;
    if (!shallow) {
        r = bvh__emit_rebuild(c, &q, map, src_count, o);
        if (r == BVH_SUCCESS && bvh__cancelled(c->prog)) r = BVH_ERROR_CANCELLED;
        goto done;
    }
    if (blocks && block_count >= 2 && blocks[block_count - 1] == src_count && !src[root].count &&
        !(cnt[root] & BVH__COLLAPSE_BIT))
        r = bvh__emit_placed(c, &q, map, src_count, nthreads, o);
    else
        r = bvh__emit_tasks(c, &q, map, src_count, nthreads, o);
    o->node_count = size[root];
    o->ref_count = prims;
done:
    if (r != BVH_SUCCESS) bvh__out_free(c, o);
    bvh__free(&c->al, cost);
    bvh__free(&c->al, height);
    bvh__free(&c->al, size);
    bvh__free(&c->al, cnt);
    return r;
}

/* ============================================================================================ */
/* == tree optimizer: parallel reinsertion (desc.optimize) ======================================= */
/* Insertion-based optimization (Bittner, Hapala & Havran 2013) in the parallel form of Meister &
   Bittner 2018, on the binary tree a builder gives before the collapse to leaves. Each round,
   a `batch` fraction of the nodes (bvh__opt_subsets) each look for the move that lowers the
   sum of interior areas most: the node leaves its place (its parent goes, its sibling takes
   the parent's place) and becomes the sibling of another node under a new parent. The searches
   run on the build's threads against the same tree; then one thread applies the moves best
   first, skipping a move that touches a node an earlier move of the round changed, and refits
   the boxes above each. Leaves move with all their primitives; the collapse and the layouts
   follow as for the builder. Differences from the paper: the candidates are a subset of the
   nodes each round (not every node), less those that nearly fill their parent's box
   (BVH__OPT_FILL), and the rounds a fixed number (no convergence test), so that nothing
   depends on time and the tree is the same for any thread count; a move whose target now lies
   below the moved node is refused (two moves of one round could otherwise close a cycle). */
/* ============================================================================================ */
#ifndef BVH__OPT_BATCH
#define BVH__OPT_BATCH 0.1f /* desc.optimize.batch's default */
#endif
#define BVH__OPT_STACK 128 /* pending nodes of one search; a full stack skips the rest, alike on every run */
typedef struct bvh__opt_move {
    float gain;  /* half area the move saves (0: none found) */
    uint32_t to; /* the new sibling's slot */
} bvh__opt_move;
typedef struct bvh__opt {
    const bvh__ctx *c;
    bvh_node *node;   /* count slots: the root at 1 (0 unused), sibling pairs at (2, 3), (4, 5)...,
                         each in one cache line; an interior node's index is its children's pair,
                         as in bvh_node */
    uint32_t *parent; /* per slot (the root's: BVH_INVALID) */
    uint32_t count;
    const uint32_t *cand; /* this round's candidates (slots, ascending): a range of `order` */
    uint32_t cand_count;
    bvh__opt_move *move; /* per candidate */
} bvh__opt;
#define BVH__OPT_ROOT 1u
BVH__INLINE uint32_t bvh__opt_sibling(uint32_t i) { return i ^ 1u; }
BVH__INLINE float bvh__opt_area(const bvh_node *n) { return bvh__half_area(bvh__node_box(n)); }
/* Best insertion below slot s for a node of box b and half area ab, when removing it saves d
   (more than best->gain so far): a branch-and-bound walk. Inserting at y costs the merged box,
   and every node from s down to y's parent grows to include b; no insertion below y can save
   more than what is left at y minus ab. `skip`: a slot not to take (the node's sibling). */
static void bvh__opt_probe(const bvh_node *nd, uint32_t s, float d, bvh_aabb b, float ab, uint32_t skip,
                           bvh__opt_move *best) {
    uint32_t stack[BVH__OPT_STACK], sp = 0;
    float left[BVH__OPT_STACK];
    stack[sp] = s;
    left[sp++] = d;
    while (sp) {
        const uint32_t y = stack[--sp];
        const float v = left[sp];
        const bvh_node *n = &nd[y];
        float g;
        if (!(v - ab > best->gain)) continue;
        if (!n->count) BVH__PREFETCH(&nd[n->index]); /* its children's line, most often read next */
        g = v - bvh__half_area(bvh__merge(bvh__node_box(n), b));
        if (g > best->gain && y != skip) {
            best->gain = g;
            best->to = y;
        }
        if (!n->count && sp + 2 <= BVH__OPT_STACK) {
            const float below = g + bvh__opt_area(n); /* y grows from its area to the merged one */
            stack[sp] = n->index + 1;
            left[sp++] = below;
            stack[sp] = n->index;
            left[sp++] = below;
        }
    }
}
/* The best move of the node in slot f (not the root). Going up from f, at each ancestor x the
   other child's subtree is searched: an insertion there leaves every box from x's parent up as
   it was, and d holds what the removal saves below: f's parent (gone) and the shrinking of each
   ancestor between it and x's parent. */
static bvh__opt_move bvh__opt_search(const bvh__opt *o, uint32_t f) {
    const bvh_node *nd = o->node;
    const bvh_aabb b = bvh__node_box(&nd[f]);
    const float ab = bvh__half_area(b);
    uint32_t x = o->parent[f], s = bvh__opt_sibling(f);
    bvh_aabb nb = bvh__node_box(&nd[s]); /* the box of x's place once f is gone */
    float d = bvh__opt_area(&nd[x]);
    bvh__opt_move best;
    best.gain = 0.0f;
    best.to = BVH_INVALID;
    bvh__opt_probe(nd, s, d, b, ab, s, &best); /* f's sibling itself: the tree as it is */
    while (x != BVH__OPT_ROOT) {
        const uint32_t y = o->parent[x];
        s = bvh__opt_sibling(x);
        bvh__opt_probe(nd, s, d, b, ab, BVH_INVALID, &best);
        nb = bvh__merge(nb, bvh__node_box(&nd[s]));
        d += bvh__opt_area(&nd[y]) - bvh__half_area(nb);
        x = y;
    }
    return best;
}
/* A candidate whose parent's area is below BVH__OPT_FILL times its own is not searched: leaving
   its place saves little, such nodes seldom find a move, and their searches cost as much as
   the others' (docs/bench, 0.9.2: the same SAH in less time). */
#ifndef BVH__OPT_FILL
#define BVH__OPT_FILL 1.5f
#endif
static void bvh__opt_search_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    const bvh__opt *o = BVH__CAST(const bvh__opt *, arg);
    uint32_t i;
    (void)team;
    for (i = tid; i < o->cand_count; i += nt) {
        const uint32_t f = o->cand[i];
        if (bvh__opt_area(&o->node[o->parent[f]]) < BVH__OPT_FILL * bvh__opt_area(&o->node[f])) {
            o->move[i].gain = 0.0f;
            o->move[i].to = BVH_INVALID;
        } else {
            o->move[i] = bvh__opt_search(o, f);
        }
    }
}
/* The rounds' candidates: `per` subsets of the slots (root excluded), by a hash of the slot, the
   next subset each round, so that `per` rounds offer every node once (taking the largest nodes
   every round instead offers the same ones again: they seldom move, and the tree improves
   several times less for the same work). The slots are sorted into their subsets once (a counting
   sort, ascending within each): order holds them, subset g at order[start[g] .. start[g + 1]). A
   round takes at most `want` of its subset, lowest slots first. */
BVH__INLINE uint32_t bvh__opt_subset(uint32_t i, uint32_t per) { return ((i * 2654435761u) >> 8) % per; }
static void bvh__opt_subsets(const bvh__opt *o, uint32_t per, uint32_t *order, uint32_t *start) {
    uint32_t i, g;
    memset(start, 0, ((size_t)per + 1) * sizeof *start);
    for (i = BVH__OPT_ROOT + 1; i < o->count; i++) start[bvh__opt_subset(i, per) + 1]++; /* sizes */
    for (g = 0; g < per; g++) start[g + 1] += start[g];                                  /* begins */
    for (i = BVH__OPT_ROOT + 1; i < o->count; i++) order[start[bvh__opt_subset(i, per)]++] = i;
    for (g = per; g > 0; g--) start[g] = start[g - 1]; /* each begin had moved to the next one's */
    start[0] = 0;
}
/* Refits the boxes of the ancestors of slot i, up to the first that keeps its box: every box
   above was its children's merge before the move and its children are unchanged, so it still is
   (min and max are exact: the same bits as refitting to the root). */
static void bvh__opt_refit(bvh__opt *o, uint32_t i) {
    while (i != BVH__OPT_ROOT) {
        bvh_node *p;
        bvh_aabb b;
        i = o->parent[i];
        p = &o->node[i];
        b = bvh__merge(bvh__node_box(&o->node[p->index]), bvh__node_box(&o->node[p->index + 1]));
        if (!memcmp(&b.min, &p->min, sizeof b.min) && !memcmp(&b.max, &p->max, sizeof b.max)) return;
        bvh__set_box(p, b);
    }
}
BVH__INLINE void bvh__opt_adopt(bvh__opt *o, uint32_t at) {
    const bvh_node *n = &o->node[at];
    if (!n->count) o->parent[n->index] = o->parent[n->index + 1] = at;
}
/* Applies the move of f next to t unless a slot it changes was changed this round, or t now lies
   below f. The pair of f and its sibling s becomes t's children: s's content moves up into the
   parent's slot p, t's content into s, and t holds the new parent. */
static int bvh__opt_apply(bvh__opt *o, uint32_t f, uint32_t t, uint8_t *touched) {
    const uint32_t s = bvh__opt_sibling(f), p = o->parent[f], pt = o->parent[t];
    uint32_t x;
    bvh_node keep;
    if (touched[f] || touched[s] || touched[p] || touched[t] || touched[pt] || t == p || t == s) return 0;
    for (x = t; x != BVH__OPT_ROOT; x = o->parent[x])
        if (x == f) return 0;
    touched[f] = touched[s] = touched[p] = touched[t] = touched[pt] = 1;
    keep = o->node[t];
    o->node[p] = o->node[s];
    bvh__opt_adopt(o, p);
    o->node[s] = keep;
    bvh__opt_adopt(o, s);
    bvh__set_box(&o->node[t], bvh__merge(bvh__node_box(&o->node[f]), bvh__node_box(&keep)));
    o->node[t].count = 0;
    o->node[t].index = f < s ? f : s;
    o->parent[f] = o->parent[s] = t;
    bvh__opt_refit(o, t);
    bvh__opt_refit(o, p);
    return 1;
}
/* Asks for the slots the move of f next to t reads first, a few moves before it is applied: the
   moves come in the order of their gains, at slots all over the tree. Only prefetches: it must
   stay inlined (see BVH__PREFETCH). */
BVH__INLINE void bvh__opt_ask(const bvh__opt *o, uint32_t f, uint32_t t, const uint8_t *touched) {
    BVH__PREFETCH(&o->node[f]);
    BVH__PREFETCH(&o->node[t]);
    BVH__PREFETCH(&o->parent[f]);
    BVH__PREFETCH(&o->parent[t]);
    BVH__PREFETCH(touched + f);
    BVH__PREFETCH(touched + t);
}
/* One round: search in parallel, then apply best first (ties: the lowest slot). The moves are
   sorted by a key of the gain's bits (positive floats order as their bits) above the slot. */
static bvh_result bvh__opt_round(bvh__opt *o, uint32_t threads, uint64_t *keys, uint32_t *vals, uint8_t *touched) {
    uint32_t i, m = 0;
    bvh_result r = bvh__run(o->c, threads, 0, bvh__opt_search_fn, o);
    if (r != BVH_SUCCESS) return r;
    for (i = 0; i < o->cand_count; i++)
        if (o->move[i].gain > 0.0f) {
            keys[m] = (uint64_t)~bvh__bits(o->move[i].gain) << 32 | o->cand[i];
            vals[m++] = i;
        }
    bvh__msd_local(keys, vals, keys + o->cand_count, vals + o->cand_count, 0, m, 64, 0);
    memset(touched, 0, o->count);
    for (i = 0; i < m; i++) {
        if (i + 8 < m) bvh__opt_ask(o, o->cand[vals[i + 8]], o->move[vals[i + 8]].to, touched);
        (void)bvh__opt_apply(o, o->cand[vals[i]], o->move[vals[i]].to, touched);
    }
    return BVH_SUCCESS;
}
/* Copies the tree below src[root] into o's slots, depth first (a node's children pair is
   appended when the node is reached, the left child's subtree next): the searches climb from a
   node to the root and walk down subtrees, and in this order the nodes of a subtree lie close
   together. `stack` has room for the tree's interior nodes. */
static void bvh__opt_load(bvh__opt *o, const bvh_node *src, uint32_t root, uint32_t *stack) {
    uint32_t sp = 0, next = BVH__OPT_ROOT + 1;
    memset(&o->node[0], 0, sizeof o->node[0]);
    o->node[BVH__OPT_ROOT] = src[root];
    o->parent[0] = o->parent[BVH__OPT_ROOT] = BVH_INVALID;
    stack[sp++] = BVH__OPT_ROOT;
    while (sp) {
        const uint32_t i = stack[--sp];
        bvh_node *n = &o->node[i];
        if (n->count) continue;
        o->node[next] = src[n->index];
        o->node[next + 1] = src[n->index + 1];
        o->parent[next] = o->parent[next + 1] = i;
        n->index = next;
        stack[sp++] = next + 1;
        stack[sp++] = next;
        next += 2;
    }
    o->count = next;
}
/* Writes o's tree to out as a source tree for bvh__emit (children adjacent and before their
   parent, the root last), breadth first from the end: a copied node's index still names its
   children's slots until its own turn comes. */
static void bvh__opt_store(const bvh__opt *o, bvh_node *out) {
    uint32_t i = o->count - 1, next = o->count - 2;
    out[next] = o->node[BVH__OPT_ROOT];
    while (i-- > 0) {
        bvh_node *n = &out[i];
        if (n->count) continue;
        next -= 2;
        out[next] = o->node[n->index];
        out[next + 1] = o->node[n->index + 1];
        n->index = next;
    }
}
/* Optimizes the binary tree below src[root] (children adjacent, leaves indexing map) for
   c->opt_rounds rounds on `threads` threads, then emits it as bvh__emit does (collapse: by the
   SAH). The tree has at most node_cap nodes; src is overwritten (the optimized tree goes there
   for bvh__emit: no second copy of the nodes). */
static bvh_result bvh__optimize_emit(const bvh__ctx *c, bvh_node *src, uint32_t root, uint32_t node_cap,
                                     const uint32_t *map, int collapse, uint32_t threads, bvh__out *out) {
    bvh__opt o;
    uint32_t round, want, per, *vals = NULL, *order = NULL, *start = NULL;
    uint64_t *keys = NULL;
    uint8_t *touched = NULL;
    bvh_result r = BVH_SUCCESS;
    memset(out, 0, sizeof *out); /* what bvh__emit frees when it fails */
    memset(&o, 0, sizeof o);
    o.c = c;
    o.node = BVH__CAST(bvh_node *, bvh__alloc_lines(&c->al, ((size_t)node_cap + 1) * sizeof(bvh_node)));
    o.parent = BVH__ALLOC(&c->al, uint32_t, (size_t)node_cap + 1);
    if (!o.node || !o.parent) {
        r = BVH_ERROR_OUT_OF_MEMORY;
        goto done;
    }
    order = BVH__ALLOC(&c->al, uint32_t, node_cap); /* the load's stack first */
    if (!order) {
        r = BVH_ERROR_OUT_OF_MEMORY;
        goto done;
    }
    bvh__opt_load(&o, src, root, order);
    per = (uint32_t)(1.0f / c->opt_batch + 0.5f);
    want = o.count / per + o.count / 64 + 1; /* a subset's size, and room for its spread */
    want = want > o.count - 2 ? o.count - 2 : want;
    if (o.count - 1 < 3) goto emit; /* a single leaf */
    start = BVH__ALLOC(&c->al, uint32_t, (size_t)per + 1);
    o.move = BVH__ALLOC(&c->al, bvh__opt_move, want);
    keys = BVH__ALLOC(&c->al, uint64_t, 2 * (size_t)want);
    vals = BVH__ALLOC(&c->al, uint32_t, 2 * (size_t)want);
    touched = BVH__ALLOC(&c->al, uint8_t, o.count);
    if (!start || !o.move || !keys || !vals || !touched) {
        r = BVH_ERROR_OUT_OF_MEMORY;
        goto done;
    }
    bvh__opt_subsets(&o, per, order, start);
    for (round = 0; round < c->opt_rounds && r == BVH_SUCCESS; round++) {
        const uint32_t g = round % per, n = start[g + 1] - start[g];
        if (bvh__report(c->prog, (double)round / (double)c->opt_rounds)) {
            r = BVH_ERROR_CANCELLED;
            break;
        }
        o.cand = order + start[g];
        o.cand_count = n < want ? n : want;
        r = bvh__opt_round(&o, threads, keys, vals, touched);
    }
    if (r != BVH_SUCCESS) goto done;
emit:
    bvh__opt_store(&o, src);
    bvh__free_lines(&c->al, o.node); /* before emission, which needs its own */
    o.node = NULL;
    r = bvh__emit(c, src, o.count - 1, map, collapse, threads, NULL, 0, out);
done:
    bvh__free(&c->al, touched);
    bvh__free(&c->al, vals);
    bvh__free(&c->al, keys);
    bvh__free(&c->al, o.move);
    bvh__free(&c->al, start);
    bvh__free(&c->al, order);
    bvh__free(&c->al, o.parent);
    bvh__free_lines(&c->al, o.node);
    return r;
}

/* ============================================================================================ */
/* == baseline bottom-up ("AABB aggregation", the study's second builder) ========================= */
/* Primitives in Morton order of their centroids; runs of max_leaf of them become the leaves (the
   same as merging one cluster per primitive pairwise for log2(max_leaf) levels); then neighbours
   are merged pairwise, level by level, until one root remains. O(n log n) for the radix sort,
   O(n) for the aggregation; the tree is balanced, depth ceil(log2(n / max_leaf)). */
/* ============================================================================================ */
static bvh_result bvh__build_bottom_up(const bvh__ctx *c, bvh__out *o) {
    bvh__morton_job job;
    bvh_node *src = NULL;
    uint32_t leaves = (c->n + c->max_leaf - 1) / c->max_leaf, cap = 2 * leaves + 64, count = 0, level, len, i;
    bvh_result r = bvh__morton_job_init(c, &job, 1);
    if (r == BVH_SUCCESS && !(src = BVH__ALLOC(&c->al, bvh_node, cap))) r = BVH_ERROR_OUT_OF_MEMORY;
    if (r != BVH_SUCCESS) goto done;
    bvh__team_run(&c->al, 1, bvh__morton_team_fn, &job);
    bvh__stage_in(c->prog, 0.5f, 1.0f);
    if (bvh__report(c->prog, 0.0)) {
        r = BVH_ERROR_CANCELLED;
        goto done;
    }
    for (i = 0; i < leaves; i++) {
        uint32_t b = i * c->max_leaf, e = b + c->max_leaf < c->n ? b + c->max_leaf : c->n, k;
        bvh_aabb box = bvh__empty();
        for (k = b; k < e; k++) box = bvh__merge(box, c->boxes[job.sort.vals[k]]);
        bvh__set_box(&src[count], box);
        src[count].index = b;
        src[count].count = e - b;
        count++;
    }
    level = 0;
    len = leaves;
    while (len > 1) {
        uint32_t next = count;
        for (i = 0; i + 1 < len; i += 2) {
            bvh_node *p = &src[count++];
            bvh__set_box(p, bvh__merge(bvh__node_box(&src[level + i]), bvh__node_box(&src[level + i + 1])));
            p->index = level + i;
            p->count = 0;
        }
        if (len & 1) src[count++] = src[level + len - 1]; /* the odd one moves up unchanged */
        level = next;
        len = count - next;
    }
    r = bvh__emit(c, src, count, job.sort.vals, 0, 1, NULL, 0, o);
done:
    bvh__free(&c->al, src);
    bvh__morton_job_free(c, &job);
    return r;
}

/* ============================================================================================ */
/* == PLOC: Parallel Locally-Ordered Clustering (Meister & Bittner 2018, Alg. 1) ================= */
/* Clusters start as one leaf per primitive in Morton order (63-bit codes, ties by index). Each
   iteration: every cluster finds its nearest neighbour within `radius` positions by the area of
   the merged box (bvh__ploc_search); mutual nearest neighbours merge; a prefix scan compacts the
   survivors. Ties in distance go to the nearest position, then to the pair (2k, 2k+1), so that
   equal boxes still halve the count. bvh__emit then collapses subtrees into leaves by the SAH.
   `ploc` is a team of one, `ploc-parallel` a team of pthreads; every phase's result is
   independent of the thread count, so both give the same tree. Differences from the paper: CPU
   threads instead of GPU work groups; the merged node replaces the left cluster before
   compaction, as the study's pseudo-code does; and the SAH top (desc.ploc.top; BVH_OFF = the
   paper's PLOC): when the clusters first number n / top or fewer, bvh__ploc_top builds a second
   top over them by binned SAH (with PLOC's own split as one more candidate) and the cheaper top
   is kept. Why and what it gives: docs/DESIGN.md. */
/* ============================================================================================ */
typedef struct bvh__nn bvh__nn;
typedef struct bvh__ploc {
    const bvh__ctx *c;
    bvh__morton_job mj;
    bvh_node *cin, *cout, *src;
    uint64_t *best;               /* per cluster: distance bits << 32 | tie key (see bvh__ploc_offer) */
    uint64_t *bnd;                /* per thread, radius entries: best offers to the next chunk's clusters */
    uint32_t *merges, *survivors; /* per thread */
    uint8_t *role;                /* per cluster, this iteration: see the merging decisions */
    bvh__nn *nn;                  /* per thread: the neighbour search's block buffers, in nn_f and nn_i */
    float *nn_f;
    int32_t *nn_i;
    uint32_t *blocks; /* end of src after each iteration, then after the root (for bvh__emit) */
    uint32_t block_count, block_cap, radius, root;
    uint32_t top_cut;                      /* bvh__ploc_top: top_m clusters were left when their count first fell */
    uint32_t top_m, top_slots, top_blocks; /* to top_cut; then src and blocks held this much */
    int stop; /* the build was cancelled (set by thread 0 before an iteration's first barrier) */
} bvh__ploc;
/* Room for every iteration's end and the root's: each iteration merges at least a 32nd of the
   clusters (or pairs them all), which bounds the count (about 660 for 2^30 primitives). */
static uint32_t bvh__ploc_block_cap(uint32_t n) {
    uint32_t k = 1, m = n;
    while (m > 1) {
        m -= m / 32 ? m / 32 : 1;
        k++;
    }
    return k;
}

/* An offer of neighbour j to cluster i as one integer, so that the best offer is a plain minimum:
   the distance's float bits (non-negative floats order like their bits; a NaN comes last), then
   the tie key |i-j| << 2 | (min(i,j) & 1) << 1 | (j > i), from which j can be recovered. The
   distance comes as a key: its bits with the sign bit flipped (see bvh__ploc_search). */
BVH__INLINE uint64_t bvh__ploc_offer(int32_t key, uint32_t dist, uint32_t lo_odd, uint32_t right) {
    uint32_t bits = (uint32_t)key ^ 0x80000000u;
    return (uint64_t)bits << 32 | dist << 2 | lo_odd << 1 | right;
}
BVH__INLINE uint32_t bvh__ploc_neighbour(uint32_t i, uint64_t best) {
    uint32_t key = (uint32_t)best, dist = key >> 2, left = (key & 1u) - 1u; /* all ones: j < i */
    return i + ((dist ^ left) - left); /* no branch: the side is a coin toss to a predictor */
}
#define BVH__MIN64(a, b) ((b) < (a) ? (b) : (a))

/* The neighbour search of one thread's clusters [b, e), block by block. For each offset k = j - i
   (1..r) the distances of the pairs (i, i + k) of a block are computed at once from the boxes as
   a structure of arrays, and kept per side: the best right neighbour of i and the best left
   neighbour of j = i + k, as (distance, k). Every loop over a block runs over contiguous arrays
   without a dependence from one element to the next (SSE, four pairs at a time); the packed
   64-bit offers of bvh__ploc_offer are formed once per cluster at the end. Distances are compared
   by their bits as bvh__ploc_offer orders them (a NaN, from an infinite extent times a zero one,
   is the worst offer but still an offer), so the result is exactly that of comparing every offer:
   smaller distance, then smaller k, then the parity and side bits. Keys are the bits with the
   sign bit flipped, so that signed 32-bit comparisons order them as unsigned ones. */
#define BVH__NN_BLOCK 256u
struct bvh__nn {          /* arrays of bvh__nn_block(n) entries (rd, rk) or that + r (the others) */
    float *lo[3], *hi[3]; /* boxes of i0 .. i0 + nb + r */
    int32_t *rd, *ld;     /* best distance key right/left */
    int32_t *rk, *lk;     /* its offset k; 0: no offer yet */
    size_t block;         /* clusters per block, bvh__nn_block(n) */
};
/* Clusters per block: BVH__NN_BLOCK, or on inputs under 4 blocks n / 4 rounded up to the vector
   width, at least 64: there the buffers are a good part of the peak memory (500 triangles: 10 of
   154 KB). The results do not depend on the block size. */
static size_t bvh__nn_block(size_t n) {
    return n >= 4 * BVH__NN_BLOCK ? BVH__NN_BLOCK : n / 4 > 64 ? (n / 4 + 7) & ~(size_t)7 : 64;
}
/* The distances of pairs (i0 + q, i0 + q + k) for q < nbr (a multiple of the vector width) and
   k = 1..r, kept as the best per side (see bvh__ploc_search). */
#ifdef BVH__AVX2
/* Eight pairs at a time; the same operations in the same order as the SSE loop, so the same bits. */
__attribute__((target("avx2"))) static void bvh__ploc_pairs8(bvh__nn *w, size_t nbr, uint32_t r, int32_t lim) {
    size_t q;
    uint32_t k;
    for (k = 1; k <= r; k++) {
        const float *lx = w->lo[0], *ly = w->lo[1], *lz = w->lo[2], *hx = w->hi[0], *hy = w->hi[1], *hz = w->hi[2];
        int32_t *rd = w->rd, *ld = w->ld + k, *rk = w->rk, *lk = w->lk + k;
        const __m256i kk = _mm256_set1_epi32((int)k), zero = _mm256_setzero_si256(),
                      flip = _mm256_set1_epi32(INT32_MIN);
        const __m256i limv = _mm256_set1_epi32(lim), lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
        for (q = 0; q < nbr; q += 8) {
            __m256 dx = _mm256_sub_ps(_mm256_max_ps(_mm256_loadu_ps(hx + q), _mm256_loadu_ps(hx + q + k)),
                                      _mm256_min_ps(_mm256_loadu_ps(lx + q), _mm256_loadu_ps(lx + q + k)));
            __m256 dy = _mm256_sub_ps(_mm256_max_ps(_mm256_loadu_ps(hy + q), _mm256_loadu_ps(hy + q + k)),
                                      _mm256_min_ps(_mm256_loadu_ps(ly + q), _mm256_loadu_ps(ly + q + k)));
            __m256 dz = _mm256_sub_ps(_mm256_max_ps(_mm256_loadu_ps(hz + q), _mm256_loadu_ps(hz + q + k)),
                                      _mm256_min_ps(_mm256_loadu_ps(lz + q), _mm256_loadu_ps(lz + q + k)));
            __m256 d =
                _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(dx, dy), _mm256_mul_ps(dy, dz)), _mm256_mul_ps(dz, dx));
            __m256i key = _mm256_xor_si256(_mm256_castps_si256(d), flip);
            __m256i ok = _mm256_cmpgt_epi32(limv, _mm256_add_epi32(_mm256_set1_epi32((int)(q + k)), lane));
            __m256i cr = _mm256_loadu_si256((const __m256i *)(const void *)(rd + q));
            __m256i cl = _mm256_loadu_si256((const __m256i *)(const void *)(ld + q));
            __m256i kr = _mm256_loadu_si256((const __m256i *)(const void *)(rk + q));
            __m256i kl = _mm256_loadu_si256((const __m256i *)(const void *)(lk + q));
            __m256i tr =
                _mm256_and_si256(ok, _mm256_or_si256(_mm256_cmpeq_epi32(kr, zero), _mm256_cmpgt_epi32(cr, key)));
            __m256i tl = _mm256_and_si256(
                ok, _mm256_or_si256(_mm256_or_si256(_mm256_cmpeq_epi32(kl, zero), _mm256_cmpgt_epi32(cl, key)),
                                    _mm256_and_si256(_mm256_cmpeq_epi32(key, cl), _mm256_cmpgt_epi32(kl, kk))));
            _mm256_storeu_si256((__m256i *)(void *)(rd + q), _mm256_blendv_epi8(cr, key, tr));
            _mm256_storeu_si256((__m256i *)(void *)(rk + q), _mm256_blendv_epi8(kr, kk, tr));
            _mm256_storeu_si256((__m256i *)(void *)(ld + q), _mm256_blendv_epi8(cl, key, tl));
            _mm256_storeu_si256((__m256i *)(void *)(lk + q), _mm256_blendv_epi8(kl, kk, tl));
        }
    }
}
/* 1 when the CPU runs AVX2 (the compiler's runtime check; the block search then takes 8 pairs),
   with FMA and POPCNT, which the 8-wide traversal's AVX2 loop uses (the fast slab test's fused
   multiply-subtract, the ordering's popcount): every CPU with AVX2 has both. */
static int bvh__have_avx2(void) {
    return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma") && __builtin_cpu_supports("popcnt") ? 1 : 0;
}
/* 1 on AMD's cores, where the fast slab test keeps float max and min (bvh__slab8_avx2 says why). */
#ifndef BVH__SLAB_FLOAT /* private; the tests set it to 0 or 1 to run the other vendor's test */
#define BVH__SLAB_FLOAT __builtin_cpu_is("amd")
#endif
static int bvh__slab_float(void) { return BVH__SLAB_FLOAT ? 1 : 0; }
#else
static int bvh__have_avx2(void) { return 0; }
#endif
static void bvh__ploc_pairs(bvh__nn *w, size_t nbr, uint32_t r, int32_t lim, int wide) {
    size_t q;
    uint32_t k;
#ifdef BVH__AVX2
    if (wide) {
        bvh__ploc_pairs8(w, nbr, r, lim);
        return;
    }
#else
    (void)wide;
#endif
    for (k = 1; k <= r; k++) {
        const float *lx = w->lo[0], *ly = w->lo[1], *lz = w->lo[2], *hx = w->hi[0], *hy = w->hi[1], *hz = w->hi[2];
        int32_t *rd = w->rd, *ld = w->ld + k, *rk = w->rk, *lk = w->lk + k;
#ifdef BVH__SSE
        const __m128i kk = _mm_set1_epi32((int)k), zero = _mm_setzero_si128(), flip = _mm_set1_epi32(INT32_MIN);
        const __m128i limv = _mm_set1_epi32(lim), lane = _mm_setr_epi32(0, 1, 2, 3);
        for (q = 0; q < nbr; q += 4) {
            __m128 dx = _mm_sub_ps(_mm_max_ps(_mm_loadu_ps(hx + q), _mm_loadu_ps(hx + q + k)),
                                   _mm_min_ps(_mm_loadu_ps(lx + q), _mm_loadu_ps(lx + q + k)));
            __m128 dy = _mm_sub_ps(_mm_max_ps(_mm_loadu_ps(hy + q), _mm_loadu_ps(hy + q + k)),
                                   _mm_min_ps(_mm_loadu_ps(ly + q), _mm_loadu_ps(ly + q + k)));
            __m128 dz = _mm_sub_ps(_mm_max_ps(_mm_loadu_ps(hz + q), _mm_loadu_ps(hz + q + k)),
                                   _mm_min_ps(_mm_loadu_ps(lz + q), _mm_loadu_ps(lz + q + k)));
            __m128 d = _mm_add_ps(_mm_add_ps(_mm_mul_ps(dx, dy), _mm_mul_ps(dy, dz)), _mm_mul_ps(dz, dx));
            __m128i key = _mm_xor_si128(_mm_castps_si128(d), flip);
            __m128i ok = _mm_cmplt_epi32(_mm_add_epi32(_mm_set1_epi32((int)(q + k)), lane), limv);
            __m128i cr = _mm_loadu_si128((const __m128i *)(const void *)(rd + q));
            __m128i cl = _mm_loadu_si128((const __m128i *)(const void *)(ld + q));
            __m128i kr = _mm_loadu_si128((const __m128i *)(const void *)(rk + q));
            __m128i kl = _mm_loadu_si128((const __m128i *)(const void *)(lk + q));
            /* right: offsets arrive in increasing k, so a strictly smaller key wins */
            __m128i tr = _mm_and_si128(ok, _mm_or_si128(_mm_cmpeq_epi32(kr, zero), _mm_cmplt_epi32(key, cr)));
            /* left (j = i0 + q + k): offers carried from the previous block have larger k */
            __m128i tl =
                _mm_and_si128(ok, _mm_or_si128(_mm_or_si128(_mm_cmpeq_epi32(kl, zero), _mm_cmplt_epi32(key, cl)),
                                               _mm_and_si128(_mm_cmpeq_epi32(key, cl), _mm_cmplt_epi32(kk, kl))));
            _mm_storeu_si128((__m128i *)(void *)(rd + q),
                             _mm_or_si128(_mm_and_si128(tr, key), _mm_andnot_si128(tr, cr)));
            _mm_storeu_si128((__m128i *)(void *)(rk + q),
                             _mm_or_si128(_mm_and_si128(tr, kk), _mm_andnot_si128(tr, kr)));
            _mm_storeu_si128((__m128i *)(void *)(ld + q),
                             _mm_or_si128(_mm_and_si128(tl, key), _mm_andnot_si128(tl, cl)));
            _mm_storeu_si128((__m128i *)(void *)(lk + q),
                             _mm_or_si128(_mm_and_si128(tl, kk), _mm_andnot_si128(tl, kl)));
        }
#else
        for (q = 0; q < nbr; q++) {
            float dx = (hx[q] > hx[q + k] ? hx[q] : hx[q + k]) - (lx[q] < lx[q + k] ? lx[q] : lx[q + k]);
            float dy = (hy[q] > hy[q + k] ? hy[q] : hy[q + k]) - (ly[q] < ly[q + k] ? ly[q] : ly[q + k]);
            float dz = (hz[q] > hz[q + k] ? hz[q] : hz[q + k]) - (lz[q] < lz[q + k] ? lz[q] : lz[q + k]);
            float d = dx * dy + dy * dz + dz * dx;
            uint32_t bits;
            int32_t key;
            if ((int32_t)(q + k) >= lim) continue;
            memcpy(&bits, &d, sizeof bits);
            key = (int32_t)(bits ^ 0x80000000u);
            if (rk[q] == 0 || key < rd[q]) {
                rd[q] = key;
                rk[q] = (int32_t)k;
            }
            if (lk[q] == 0 || key < ld[q] || (key == ld[q] && (int32_t)k < lk[q])) {
                ld[q] = key;
                lk[q] = (int32_t)k;
            }
        }
#endif
    }
}
static void bvh__ploc_search(bvh__nn *w, const bvh_node *cin, uint32_t count, uint32_t r, size_t b, size_t e,
                             uint64_t *best, uint64_t *bnd) {
    size_t i0, q, i;
    const int wide = bvh__have_avx2();
    const size_t vw = wide ? 8 : 4;
    for (q = 0; q < r; q++) {
        w->ld[q] = 0;
        w->lk[q] = 0;
    }
    for (i0 = b; i0 < e; i0 += w->block) {
        /* Rounded up to the vector width (8 pairs at a time with AVX2, else 4): clusters past e
           make genuine offers, which the thread that owns them makes too (a minimum does not mind
           a repeated offer), and their own results are not used; pairs reaching past the last
           cluster are masked out. */
        size_t nb = e - i0 < w->block ? e - i0 : w->block, nbr = (nb + vw - 1) & ~(vw - 1);
        const int32_t lim = (int32_t)(count - i0); /* pair (i0 + q, i0 + q + k) exists iff q + k < lim */
        for (q = 0; q < nbr + r; q++) {
            if (i0 + q < count) {
                const bvh_node *n = &cin[i0 + q];
                w->lo[0][q] = n->min.x;
                w->lo[1][q] = n->min.y;
                w->lo[2][q] = n->min.z;
                w->hi[0][q] = n->max.x;
                w->hi[1][q] = n->max.y;
                w->hi[2][q] = n->max.z;
            } else {
                w->lo[0][q] = w->lo[1][q] = w->lo[2][q] = w->hi[0][q] = w->hi[1][q] = w->hi[2][q] = 0.0f;
            }
        }
        for (q = 0; q < nbr; q++) {
            w->rd[q] = 0;
            w->rk[q] = 0;
            w->ld[r + q] = 0;
            w->lk[r + q] = 0;
        }
        bvh__ploc_pairs(w, nbr, r, lim, wide);
        for (q = 0; q < nb; q++) {
            uint64_t right = ~(uint64_t)0, left = ~(uint64_t)0;
            i = i0 + q;
            if (w->rk[q]) right = bvh__ploc_offer(w->rd[q], (uint32_t)w->rk[q], (uint32_t)i & 1u, 1);
            if (w->lk[q])
                left = bvh__ploc_offer(w->ld[q], (uint32_t)w->lk[q], (uint32_t)(i - (uint32_t)w->lk[q]) & 1u, 0);
            best[i] = BVH__MIN64(left, right);
        }
        /* the left offers to the next r clusters move to the front */
        memmove(w->ld, w->ld + nb, r * sizeof(int32_t));
        memmove(w->lk, w->lk + nb, r * sizeof(int32_t));
    }
    for (q = 0; q < r; q++) { /* offers to the next thread's first clusters */
        i = e + q;
        bnd[q] = ~(uint64_t)0;
        if (b < e && i < count && w->lk[q])
            bnd[q] = bvh__ploc_offer(w->ld[q], (uint32_t)w->lk[q], (uint32_t)(i - (uint32_t)w->lk[q]) & 1u, 0);
    }
}

/* First team run: Morton codes, radix sort, one leaf cluster per primitive in Morton order. */
/* The clusters of thread tid's share of the sorted primitives. */
static void bvh__ploc_cin_part(bvh__ploc *p, uint32_t tid, uint32_t nt) {
    const bvh__ctx *c = p->c;
    size_t b, e, i;
    bvh__range(c->n, tid, nt, &b, &e);
    for (i = b; i < e; i++) {
        if (i + BVH__GATHER_AHEAD < e) { /* the boxes are read in Morton order, at random: ask ahead */
            const char *x = (const char *)&c->boxes[p->mj.sort.vals[i + BVH__GATHER_AHEAD]];
            BVH__PREFETCH(x);
            BVH__PREFETCH(x + sizeof(bvh_aabb) - 1);
        }
        bvh__set_box(&p->cin[i], c->boxes[p->mj.sort.vals[i]]);
        p->cin[i].index = (uint32_t)i;
        p->cin[i].count = 1;
    }
}
static void bvh__ploc_init_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    bvh__ploc *p = BVH__CAST(bvh__ploc *, arg);
    bvh__morton_codes_team(&p->mj, tid, nt, team);
    bvh__ploc_cin_part(p, tid, nt);
}
/* bvh__ploc_init_fn on a caller's pool, whose tasks must not meet: cut at its barriers into
   steps, a run each, the decisions between them (which pass, whether to skip it) taken by the
   calling thread from the same histograms as a team's threads take them, so the same order. */
typedef struct bvh__ploc_init_run {
    bvh__ploc *p;
    int step, shift;
} bvh__ploc_init_run;
static void bvh__ploc_init_task(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    const bvh__ploc_init_run *x = BVH__CAST(const bvh__ploc_init_run *, arg);
    bvh__sort *s = &x->p->mj.sort;
    uint32_t local[BVH__RADIX_SIZE];
    size_t b, e;
    (void)team;
    bvh__range(s->n, tid, nt, &b, &e);
    if (x->step == 0) { /* codes, and the histogram of their top digits */
        bvh__morton_codes_part(&x->p->mj, tid, nt);
        bvh__radix_hist(s, tid, b, e, x->shift);
    } else if (x->step == 1) { /* an LSD pass's histogram */
        bvh__radix_hist(s, tid, b, e, x->shift);
    } else if (x->step == 2) {
        bvh__radix_offsets(s, tid, nt, local);
        bvh__radix_move(s, local, x->shift, b, e);
    } else if (x->step == 3) {
        bvh__radix_ranges(s, nt, b, e);
    } else {
        bvh__ploc_cin_part(x->p, tid, nt);
    }
}
static bvh_result bvh__ploc_init_step(bvh__ploc_init_run *x, int step, uint32_t nt) {
    x->step = step;
    return bvh__run(x->p->c, nt, 0, bvh__ploc_init_task, x);
}
static bvh_result bvh__ploc_init_steps(bvh__ploc *p, uint32_t nt) {
    const int top = 64 - BVH__RADIX_BITS;
    bvh__ploc_init_run x;
    bvh__sort *s = &p->mj.sort;
    bvh_result r;
    x.p = p;
    x.shift = top;
    if ((r = bvh__ploc_init_step(&x, 0, nt)) != BVH_SUCCESS) return r;
    if (bvh__radix_big(s, nt) && nt > 1) { /* bvh__radix_lsd_team */
        for (x.shift = 0; x.shift < 64; x.shift += BVH__RADIX_BITS) {
            if ((r = bvh__ploc_init_step(&x, 1, nt)) != BVH_SUCCESS) return r;
            if (bvh__radix_one_digit(s, nt)) continue;
            if ((r = bvh__ploc_init_step(&x, 2, nt)) != BVH_SUCCESS) return r;
            bvh__radix_swap(s);
        }
    } else {
        if ((r = bvh__ploc_init_step(&x, 2, nt)) != BVH_SUCCESS) return r;
        if ((r = bvh__ploc_init_step(&x, 3, nt)) != BVH_SUCCESS) return r;
    }
    return bvh__ploc_init_step(&x, 4, nt);
}

/* The clustering loop, cut at its four barriers into steps, so that a team runs it with barriers
   between the steps (bvh__ploc_team_fn) and a caller's pool as one run per step
   (bvh__ploc_steps): the same code, the same tree. Between steps the loop's state is
   bvh__ploc_iter: each thread of a team keeps its own copy (all compute the same); under a pool
   the calling thread keeps the one copy. */
typedef struct bvh__ploc_iter {
    bvh_node *cin, *cout;
    uint32_t count, slots, active; /* clusters; src entries written; threads with work */
} bvh__ploc_iter;
/* Before an iteration: where the SAH top would start, the threads with work and (thread 0 of a
   team, or the pool's caller: `lead`) the progress report, whose cancel every thread reads
   after the iteration's first barrier. */
static void bvh__ploc_begin(bvh__ploc *p, bvh__ploc_iter *it, uint32_t nt, int lead) {
    const bvh__ctx *c = p->c;
    if (lead && !p->top_m && it->count <= p->top_cut) { /* where the SAH top would start */
        p->top_m = it->count;
        p->top_slots = it->slots;
        p->top_blocks = p->block_count;
    }
    it->active = it->count / (4 * p->radius + 256);
    if (it->active < 1) it->active = 1;
    if (it->active > nt) it->active = nt;
    if (lead) p->stop = bvh__report(c->prog, 1.0 - (double)it->count / (double)c->n);
}
/* Merges and survivors of the iteration, from every thread's counts: fewer than 1/32 of the
   clusters merging (nested or chained input would otherwise take O(n) iterations, O(n^2) time)
   makes the iteration pair neighbours (2k, 2k+1) instead, as the bottom-up builder does, which
   halves the count. Decided from the totals, so every thread count takes the same path. */
static int bvh__ploc_totals(const bvh__ploc *p, uint32_t count, uint32_t nt, uint32_t *surv, uint32_t *merge) {
    uint32_t t;
    *surv = *merge = 0;
    for (t = 0; t < nt; t++) {
        *surv += p->survivors[t];
        *merge += p->merges[t];
    }
    if (*merge * 32 >= count) return 0;
    *merge = count / 2;
    *surv = count - *merge;
    return 1;
}
/* Step k of an iteration for thread tid of nt; a barrier (or the end of a pool run) follows each. */
static void bvh__ploc_step(bvh__ploc *p, const bvh__ploc_iter *it, int k, uint32_t tid, uint32_t nt) {
    bvh_node *cin = it->cin, *cout = it->cout;
    uint64_t *best = p->best;
    uint32_t r = p->radius, count = it->count, slots = it->slots, t, pos = 0, slot = 0, tm, ts;
    size_t b = 0, e = 0, i;
    if (tid < it->active) bvh__range(count, tid, it->active, &b, &e);
    if (k == 0) { /* nearest neighbour search: pairs (i, j), i < j <= i + r, each computed once */
        bvh__ploc_search(&p->nn[tid], cin, count, r, b, e, best, p->bnd + (size_t)tid * r);
    } else if (k == 1) {
        if (tid > 0 && tid < it->active) { /* offers from pairs that start in the previous chunk */
            const uint64_t *prev = p->bnd + (size_t)(tid - 1) * r;
            for (t = 0; t < r && b + t < e; t++) best[b + t] = BVH__MIN64(best[b + t], prev[t]);
        }
    } else if (k == 2) { /* merging decisions: count merges and survivors per chunk */
        uint32_t m = 0, sv = 0;
        for (i = b; i < e; i++) { /* role: 0 survives alone, 1 merges with j > i, 2 is merged into j < i */
            uint32_t j = bvh__ploc_neighbour((uint32_t)i, best[i]);
            uint32_t mutual = bvh__ploc_neighbour(j, best[j]) == i, left = mutual & (i < j);
            p->role[i] = (uint8_t)(mutual + (mutual & !left));
            sv += 1u - (mutual & !left);
            m += left;
        }
        p->merges[tid] = m;
        p->survivors[tid] = sv;
    } else if (bvh__ploc_totals(p, count, nt, &ts, &tm)) { /* pair neighbours (see bvh__ploc_totals) */
        for (i = b + (b & 1); i < e; i += 2) {
            size_t h = i / 2;
            if (i + 1 < count) {
                size_t sl = slots + 2 * h;
                bvh_node *n = &cout[h];
                p->src[sl] = cin[i];
                p->src[sl + 1] = cin[i + 1];
                bvh__set_box(n, bvh__merge(bvh__node_box(&cin[i]), bvh__node_box(&cin[i + 1])));
                n->index = (uint32_t)sl;
                n->count = 0;
            } else {
                cout[h] = cin[i];
            }
        }
    } else { /* merge and compact, at the positions the earlier chunks' counts give */
        for (t = 0; t < tid; t++) {
            pos += p->survivors[t];
            slot += 2 * p->merges[t];
        }
        slot += slots;
        for (i = b; i < e; i++) {
            uint8_t role = p->role[i];
            if (role == 1) {
                uint32_t j = bvh__ploc_neighbour((uint32_t)i, best[i]);
                bvh_node *n = &cout[pos++];
                p->src[slot] = cin[i];
                p->src[slot + 1] = cin[j];
                bvh__set_box(n, bvh__merge(bvh__node_box(&cin[i]), bvh__node_box(&cin[j])));
                n->index = slot;
                n->count = 0;
                slot += 2;
            } else if (role == 0) {
                cout[pos++] = cin[i];
            }
        }
    }
}
/* After an iteration's last step: the next one's state; `lead` records where the iteration ended. */
static void bvh__ploc_advance(bvh__ploc *p, bvh__ploc_iter *it, uint32_t nt, int lead) {
    uint32_t surv, merge;
    bvh_node *tmp = it->cin;
    bvh__ploc_totals(p, it->count, nt, &surv, &merge);
    it->slots += 2 * merge;
    it->count = surv;
    if (lead) {
        if (p->block_count < p->block_cap) p->blocks[p->block_count] = it->slots;
        p->block_count++;
    }
    it->cin = it->cout;
    it->cout = tmp;
}
static void bvh__ploc_iter_init(const bvh__ploc *p, bvh__ploc_iter *it) {
    it->cin = p->cin;
    it->cout = p->cout;
    it->count = p->c->n;
    it->slots = 0;
    it->active = 1;
}
/* After the last iteration (unless cancelled): the root. */
static void bvh__ploc_finish(bvh__ploc *p, const bvh__ploc_iter *it) {
    p->src[it->slots] = it->cin[0];
    p->root = it->slots;
    if (p->block_count < p->block_cap) p->blocks[p->block_count] = it->slots + 1;
    p->block_count++;
}
/* Second team run: the clustering loop. */
static void bvh__ploc_team_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    bvh__ploc *p = BVH__CAST(bvh__ploc *, arg);
    bvh__ploc_iter it;
    int k;
    bvh__ploc_iter_init(p, &it);
    while (it.count > 1) {
        bvh__ploc_begin(p, &it, nt, tid == 0);
        for (k = 0; k < 4; k++) {
            bvh__ploc_step(p, &it, k, tid, nt);
            bvh__team_sync(team);
            if (k == 0 && p->stop) break; /* read by all between the first and second barrier */
        }
        if (k < 4) return;
        bvh__ploc_advance(p, &it, nt, tid == 0);
    }
    if (tid == 0) bvh__ploc_finish(p, &it);
}
/* The clustering loop on a caller's pool: each step one run of nt tasks. */
typedef struct bvh__ploc_run {
    bvh__ploc *p;
    const bvh__ploc_iter *it;
    int k;
} bvh__ploc_run;
static void bvh__ploc_step_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    const bvh__ploc_run *x = BVH__CAST(const bvh__ploc_run *, arg);
    (void)team;
    bvh__ploc_step(x->p, x->it, x->k, tid, nt);
}
static bvh_result bvh__ploc_steps(bvh__ploc *p, uint32_t nt) {
    bvh__ploc_iter it;
    bvh__ploc_run x;
    bvh_result r;
    bvh__ploc_iter_init(p, &it);
    x.p = p;
    x.it = &it;
    while (it.count > 1) {
        bvh__ploc_begin(p, &it, nt, 1);
        if (p->stop) return BVH_SUCCESS;
        for (x.k = 0; x.k < 4; x.k++)
            if ((r = bvh__run(p->c, nt, 0, bvh__ploc_step_fn, &x)) != BVH_SUCCESS) return r;
        bvh__ploc_advance(p, &it, nt, 1);
    }
    bvh__ploc_finish(p, &it);
    return BVH_SUCCESS;
}

/* -- SAH top over PLOC's clusters ------------------------------------------------------------ */
/* Four floats (SSE where there is SSE): the binned SAH top works on boxes as lanes 0-2. */
#ifdef BVH__SSE
typedef __m128 bvh__f4;
BVH__INLINE bvh__f4 bvh__f4_at(const void *p) { return _mm_loadu_ps((const float *)p); }
/* lanes 0-2 of p, lane 3 zero (a node's index or count there would be a denormal float: slow) */
BVH__INLINE bvh__f4 bvh__f4_at3(const void *p) {
    return _mm_and_ps(_mm_loadu_ps((const float *)p), _mm_castsi128_ps(_mm_set_epi32(0, -1, -1, -1)));
}
BVH__INLINE bvh__f4 bvh__f4_set(float x) { return _mm_set1_ps(x); }
BVH__INLINE bvh__f4 bvh__f4_min(bvh__f4 a, bvh__f4 b) { return _mm_min_ps(a, b); }
BVH__INLINE bvh__f4 bvh__f4_max(bvh__f4 a, bvh__f4 b) { return _mm_max_ps(a, b); }
BVH__INLINE bvh__f4 bvh__f4_add(bvh__f4 a, bvh__f4 b) { return _mm_add_ps(a, b); }
BVH__INLINE bvh__f4 bvh__f4_sub(bvh__f4 a, bvh__f4 b) { return _mm_sub_ps(a, b); }
BVH__INLINE bvh__f4 bvh__f4_mul(bvh__f4 a, bvh__f4 b) { return _mm_mul_ps(a, b); }
BVH__INLINE void bvh__f4_put(float *p, bvh__f4 a) { _mm_storeu_ps(p, a); }
BVH__INLINE void bvh__f4_slots(uint32_t *p, bvh__f4 a) { /* lanes 0-2 truncated, without a trip through memory */
    __m128i x = _mm_cvttps_epi32(a);
    p[0] = (uint32_t)_mm_cvtsi128_si32(x);
    p[1] = (uint32_t)_mm_cvtsi128_si32(_mm_shuffle_epi32(x, 1));
    p[2] = (uint32_t)_mm_cvtsi128_si32(_mm_shuffle_epi32(x, 2));
}
#else
typedef struct bvh__f4 {
    float v[4];
} bvh__f4;
BVH__INLINE bvh__f4 bvh__f4_at(const void *p) {
    bvh__f4 r;
    memcpy(r.v, p, sizeof r.v);
    return r;
}
BVH__INLINE bvh__f4 bvh__f4_at3(const void *p) {
    bvh__f4 r;
    memcpy(r.v, p, 3 * sizeof(float));
    r.v[3] = 0.0f;
    return r;
}
BVH__INLINE bvh__f4 bvh__f4_set(float x) {
    bvh__f4 r;
    r.v[0] = r.v[1] = r.v[2] = r.v[3] = x;
    return r;
}
#define BVH__F4_OP(name, expr)                                                                                         \
    BVH__INLINE bvh__f4 name(bvh__f4 a, bvh__f4 b) {                                                                   \
        bvh__f4 r;                                                                                                     \
        int k;                                                                                                         \
        for (k = 0; k < 4; k++) r.v[k] = expr;                                                                         \
        return r;                                                                                                      \
    }
BVH__F4_OP(bvh__f4_min, a.v[k] < b.v[k] ? a.v[k] : b.v[k])
BVH__F4_OP(bvh__f4_max, a.v[k] > b.v[k] ? a.v[k] : b.v[k])
BVH__F4_OP(bvh__f4_add, a.v[k] + b.v[k])
BVH__F4_OP(bvh__f4_sub, a.v[k] - b.v[k])
BVH__F4_OP(bvh__f4_mul, a.v[k] * b.v[k])
BVH__INLINE void bvh__f4_put(float *p, bvh__f4 a) { memcpy(p, a.v, sizeof a.v); }
BVH__INLINE void bvh__f4_slots(uint32_t *p, bvh__f4 a) {
    int k;
    for (k = 0; k < 3; k++) p[k] = (uint32_t)a.v[k];
}
#endif
/* The half area of lanes 0-2, summed (xy + zx) + yz where bvh__half_area sums (xy + yz) + zx: the
   same quantity rounded differently, so PLOC's top keeps its own (its trees depend on it). */
#ifdef BVH__SSE
BVH__INLINE float bvh__f4_half_area(bvh__f4 lo, bvh__f4 hi) { /* in registers */
    __m128 d = _mm_sub_ps(hi, lo), p = _mm_mul_ps(d, _mm_shuffle_ps(d, d, _MM_SHUFFLE(3, 0, 2, 1)));
    __m128 s = _mm_add_ps(p, _mm_movehl_ps(p, p)); /* xy + zx, yz + 0 */
    return _mm_cvtss_f32(_mm_add_ss(s, _mm_shuffle_ps(s, s, _MM_SHUFFLE(1, 1, 1, 1))));
}
#else
BVH__INLINE float bvh__f4_half_area(bvh__f4 lo, bvh__f4 hi) {
    float d[4];
    bvh__f4_put(d, bvh__f4_sub(hi, lo));
    return d[0] * d[1] + d[2] * d[0] + d[1] * d[2];
}
#endif

#define BVH__TOP_BINS 32
#define BVH__TOP_CLUSTER 0x80000000u
#define BVH__TOP_NONE 0xffffffffu
#define BVH__TOP_PLOC_MIN 64 /* PLOC's split is a candidate from this many clusters up */
/* The top's nodes are bvh_node with the children in index and count (top bit: a cluster). */
/* Clusters [b, e) of buffer `buf` (0 or 1) become internal node `id` and the nodes below it (ids
   in pre-order: the left subtree from id + 1, the right from id + its left count); lo, hi: the
   bounds of their boxes; clo, chi: a range of their centroids (doubled: lo + hi) to bin over. */
typedef struct bvh__top_task {
    bvh__f4 lo, hi, clo, chi;
    uint32_t id, b, e, buf, pmin, pmax;
} bvh__top_task;
typedef struct bvh__top_bin {
    bvh__f4 lo, hi;
} bvh__top_bin;
typedef struct bvh__top_job {
    bvh_node *v[2]; /* the clusters (index: their place in PLOC's order) and a second buffer */
    bvh_node *nodes;
    bvh__top_task *tasks;
    /* PLOC's top, by x = place in src - top_slots: parent, first cluster, clusters below, the
       left child's clusters; leaf[k]: the x of cluster k */
    const uint32_t *par, *first, *cc, *lcc, *leaf;
    uint32_t task_count, busy, grain;
#ifndef BVH_NO_THREADS
    pthread_mutex_t mutex; /* the queue's (not the team's: a caller's pool runs it too) */
    pthread_cond_t cond;
#endif
} bvh__top_job;
BVH__INLINE bvh__f4 bvh__top_centre(const bvh_node *x) {
    return bvh__f4_add(bvh__f4_at3(&x->min), bvh__f4_at3(&x->max));
}
/* The bin of centre c (doubled) on each axis, clamped to [0, last]: binning and partition agree. */
BVH__INLINE void bvh__top_slots(bvh__f4 c, const bvh__top_task *t, bvh__f4 scale, bvh__f4 last, uint32_t s[3]) {
    bvh__f4_slots(s, bvh__f4_min(bvh__f4_max(bvh__f4_mul(bvh__f4_sub(c, t->clo), scale), bvh__f4_set(0.0f)), last));
}
static void bvh__top_bounds(const bvh_node *v, uint32_t b, uint32_t e, bvh__top_task *t) {
    bvh__f4 lo = bvh__f4_set(BVH_INF), hi = bvh__f4_set(-BVH_INF), clo = lo, chi = hi;
    uint32_t i, pmin = BVH__TOP_NONE, pmax = 0;
    for (i = b; i < e; i++) {
        bvh__f4 l = bvh__f4_at3(&v[i].min), h = bvh__f4_at3(&v[i].max), c = bvh__f4_add(l, h);
        lo = bvh__f4_min(lo, l);
        hi = bvh__f4_max(hi, h);
        clo = bvh__f4_min(clo, c);
        chi = bvh__f4_max(chi, c);
        pmin = v[i].index < pmin ? v[i].index : pmin;
        pmax = v[i].index > pmax ? v[i].index : pmax;
    }
    t->lo = lo;
    t->hi = hi;
    t->clo = clo;
    t->chi = chi;
    t->b = b;
    t->e = e;
    t->pmin = pmin;
    t->pmax = pmax;
}
/* PLOC's own split of clusters in [a, b] (a < b; clusters numbered in PLOC's left-to-right
   order): that of their lowest common ancestor in PLOC's top, as the first cluster number on
   its right. */
static uint32_t bvh__top_ploc_split(const bvh__top_job *j, uint32_t a, uint32_t b) {
    uint32_t y = j->par[j->leaf[a]];
    while (j->first[y] + j->cc[y] <= b) y = j->par[y];
    return j->first[y] + j->lcc[y];
}
/* Splits task t (two clusters or more) by binned SAH over the centroids (per axis, as many bins
   as clusters up to BVH__TOP_BINS), writes its node and returns in kids its children that hold
   two or more clusters (how many: the result). The clusters are partitioned into the other
   buffer without a branch; the children's boxes come from the bins, their centroid ranges from
   their boxes and the split plane (a range only needs to be near the centroids' bounds: slots
   are clamped). The middle of the range when no plane separates. */
/* Node `id` over two or three clusters at v: for three, the pair whose box is smallest goes
   under node id + 1 (the best of the three trees); no bins. */
static void bvh__top_put(bvh_node *d, bvh__f4 lo, bvh__f4 hi) {
    float l[4], h[4];
    bvh__f4_put(l, lo);
    bvh__f4_put(h, hi);
    d->min.x = l[0];
    d->min.y = l[1];
    d->min.z = l[2];
    d->max.x = h[0];
    d->max.y = h[1];
    d->max.z = h[2];
}
static void bvh__top_small(const bvh__top_job *j, const bvh__top_task *t) {
    const bvh_node *v = j->v[t->buf] + t->b;
    bvh_node *node = &j->nodes[t->id];
    bvh__top_put(node, t->lo, t->hi);
    if (t->e - t->b == 2) {
        node->index = BVH__TOP_CLUSTER | v[0].index;
        node->count = BVH__TOP_CLUSTER | v[1].index;
    } else {
        static const uint8_t pairs[3][3] = {{0, 1, 2}, {0, 2, 1}, {1, 2, 0}};
        bvh__f4 lo[3], hi[3], plo[3], phi[3];
        float best = BVH_INF;
        int k, q = 0;
        for (k = 0; k < 3; k++) {
            lo[k] = bvh__f4_at3(&v[k].min);
            hi[k] = bvh__f4_at3(&v[k].max);
        }
        for (k = 0; k < 3; k++) {
            float a;
            plo[k] = bvh__f4_min(lo[pairs[k][0]], lo[pairs[k][1]]);
            phi[k] = bvh__f4_max(hi[pairs[k][0]], hi[pairs[k][1]]);
            a = bvh__f4_half_area(plo[k], phi[k]);
            if (a < best) {
                best = a;
                q = k;
            }
        }
        node->index = t->id + 1;
        node->count = BVH__TOP_CLUSTER | v[pairs[q][2]].index;
        bvh__top_put(node + 1, plo[q], phi[q]);
        node[1].index = BVH__TOP_CLUSTER | v[pairs[q][0]].index;
        node[1].count = BVH__TOP_CLUSTER | v[pairs[q][1]].index;
    }
}
static uint32_t bvh__top_split(const bvh__top_job *j, const bvh__top_task *t, bvh__top_task kids[2]) {
    uint32_t b = t->b, e = t->e, n = e - b, nb = n < BVH__TOP_BINS ? n : BVH__TOP_BINS, i, k, mid = b, out = 0, bb = 0;
    bvh_node *v = j->v[t->buf], *w = j->v[t->buf ^ 1u], *node = &j->nodes[t->id];
    float ext[4], best = BVH_INF;
    uint32_t ps, pc[2] = {0, 0};
    bvh__f4 plo[2], phi[2];
    int ba = -1, a;
    bvh__f4 scale, last = bvh__f4_set((float)(nb - 1)), blo[2], bhi[2];
    if (n <= 3) {
        bvh__top_small(j, t);
        return 0;
    }
    bvh__f4_put(ext, bvh__f4_sub(t->chi, t->clo));
    bvh__top_put(node, t->lo, t->hi);
    {
        float s[4];
        for (a = 0; a < 3; a++) s[a] = ext[a] > 0.0f ? (float)nb / ext[a] : 0.0f;
        s[3] = 0.0f;
        scale = bvh__f4_at(s);
    }
    blo[0] = blo[1] = bvh__f4_set(BVH_INF);
    bhi[0] = bhi[1] = bvh__f4_set(-BVH_INF);
    ps = n >= BVH__TOP_PLOC_MIN && t->pmin < t->pmax ? bvh__top_ploc_split(j, t->pmin, t->pmax) : 0;
    { /* n >= 4 here */
        /* two sets of bins, even and odd clusters, so that neighbours (which often share a bin)
           do not wait for each other's update */
        bvh__top_bin bin[2][3][BVH__TOP_BINS];
        uint32_t cnt[2][3][BVH__TOP_BINS], sets = n >= 64 ? 2 : 1, qm = sets - 1, q;
        for (q = 0; q < sets; q++)
            for (a = 0; a < 3; a++)
                for (k = 0; k < nb; k++) {
                    bin[q][a][k].lo = bvh__f4_set(BVH_INF);
                    bin[q][a][k].hi = bvh__f4_set(-BVH_INF);
                    cnt[q][a][k] = 0;
                }
        plo[0] = plo[1] = bvh__f4_set(BVH_INF);
        phi[0] = phi[1] = bvh__f4_set(-BVH_INF);
        for (i = b; i < e; i++) {
            uint32_t s[3], side = v[i].index >= ps;
            bvh__top_bin *x;
            bvh__f4 l = bvh__f4_at3(&v[i].min), h = bvh__f4_at3(&v[i].max);
            q = i & qm;
            bvh__top_slots(bvh__f4_add(l, h), t, scale, last, s);
            x = &bin[q][0][s[0]];
            x->lo = bvh__f4_min(x->lo, l);
            x->hi = bvh__f4_max(x->hi, h);
            x = &bin[q][1][s[1]];
            x->lo = bvh__f4_min(x->lo, l);
            x->hi = bvh__f4_max(x->hi, h);
            x = &bin[q][2][s[2]];
            x->lo = bvh__f4_min(x->lo, l);
            x->hi = bvh__f4_max(x->hi, h);
            cnt[q][0][s[0]]++;
            cnt[q][1][s[1]]++;
            cnt[q][2][s[2]]++;
            plo[side] = bvh__f4_min(plo[side], l);
            phi[side] = bvh__f4_max(phi[side], h);
            pc[side]++;
        }
        if (ps && pc[0] && pc[1]) { /* PLOC's split of these clusters, costed the same way */
            float cost =
                bvh__f4_half_area(plo[0], phi[0]) * (float)pc[0] + bvh__f4_half_area(plo[1], phi[1]) * (float)pc[1];
            if (cost < best) {
                best = cost;
                ba = 3;
            }
        }
        for (a = 0; a < 3; a++) {
            float right[BVH__TOP_BINS];
            bvh__f4 lo = bvh__f4_set(BVH_INF), hi = bvh__f4_set(-BVH_INF);
            uint32_t c = 0;
            if (!(ext[a] > 0.0f)) continue;
            for (k = 0; qm && k < nb; k++) {
                bin[0][a][k].lo = bvh__f4_min(bin[0][a][k].lo, bin[1][a][k].lo);
                bin[0][a][k].hi = bvh__f4_max(bin[0][a][k].hi, bin[1][a][k].hi);
                cnt[0][a][k] += cnt[1][a][k];
            }
            for (k = nb - 1; k > 0; k--) {
                lo = bvh__f4_min(lo, bin[0][a][k].lo);
                hi = bvh__f4_max(hi, bin[0][a][k].hi);
                c += cnt[0][a][k];
                right[k] = c ? bvh__f4_half_area(lo, hi) * (float)c : -1.0f;
            }
            lo = bvh__f4_set(BVH_INF);
            hi = bvh__f4_set(-BVH_INF);
            c = 0;
            for (k = 0; k + 1 < nb; k++) {
                float cost;
                lo = bvh__f4_min(lo, bin[0][a][k].lo);
                hi = bvh__f4_max(hi, bin[0][a][k].hi);
                c += cnt[0][a][k];
                if (!c || right[k + 1] < 0.0f) continue;
                cost = bvh__f4_half_area(lo, hi) * (float)c + right[k + 1];
                if (cost < best) {
                    best = cost;
                    ba = a;
                    bb = k;
                }
            }
        }
        if (ba == 3) {
            blo[0] = plo[0];
            blo[1] = plo[1];
            bhi[0] = phi[0];
            bhi[1] = phi[1];
        } else if (ba >= 0)
            for (k = 0; k < nb; k++) {
                q = k > bb; /* the side of bin k */
                blo[q] = bvh__f4_min(blo[q], bin[0][ba][k].lo);
                bhi[q] = bvh__f4_max(bhi[q], bin[0][ba][k].hi);
            }
    }
    if (ba >= 0) { /* left side from b up, right side from e - 1 down */
        uint32_t l = b, r = e - 1, pmin[2] = {BVH__TOP_NONE, BVH__TOP_NONE}, pmax[2] = {0, 0};
        int axis = ba < 3 ? ba : 0;
        for (i = b; i < e; i++) {
            uint32_t s[3], left, at, id = v[i].index;
            bvh__top_slots(bvh__top_centre(&v[i]), t, scale, last, s);
            left = ba == 3 ? id < ps : s[axis] <= bb;
            at = left ? l : r;
            w[at] = v[i];
            l += left;
            r -= 1u - left;
            pmin[1 - left] = id < pmin[1 - left] ? id : pmin[1 - left];
            pmax[1 - left] = id > pmax[1 - left] ? id : pmax[1 - left];
        }
        mid = l;
        /* centroid ranges: within twice the child's box and the parent's range */
        for (k = 0; k < 2; k++) {
            kids[k].clo = bvh__f4_max(t->clo, bvh__f4_add(blo[k], blo[k]));
            kids[k].chi = bvh__f4_min(t->chi, bvh__f4_add(bhi[k], bhi[k]));
            kids[k].lo = blo[k];
            kids[k].hi = bhi[k];
            kids[k].buf = t->buf ^ 1u;
            kids[k].pmin = pmin[k];
            kids[k].pmax = pmax[k];
        }
        kids[0].b = b;
        kids[0].e = mid;
        kids[1].b = mid;
        kids[1].e = e;
    }
    if (ba < 0 || mid == b || mid == e) { /* in place: the middle of the range */
        mid = b + n / 2;
        bvh__top_bounds(v, b, mid, &kids[0]);
        bvh__top_bounds(v, mid, e, &kids[1]);
        kids[0].buf = kids[1].buf = t->buf;
        w = v;
    }
    kids[0].id = t->id + 1;
    kids[1].id = t->id + (mid - b);
    node->index = mid - b == 1 ? BVH__TOP_CLUSTER | w[b].index : kids[0].id;
    node->count = e - mid == 1 ? BVH__TOP_CLUSTER | w[mid].index : kids[1].id;
    if (mid - b > 1) out++;
    if (e - mid > 1) {
        if (!out) kids[0] = kids[1];
        out++;
    }
    return out;
}
/* The whole subtree of task t, depth first, the larger side waiting (at most log2 n + 1 tasks wait). */
static void bvh__top_subtree(const bvh__top_job *j, const bvh__top_task *t) {
    bvh__top_task st[40];
    uint32_t sp = 0;
    st[sp++] = *t;
    while (sp) {
        bvh__top_task cur = st[--sp], kids[2];
        uint32_t k = bvh__top_split(j, &cur, kids);
        if (k == 2 && kids[0].e - kids[0].b < kids[1].e - kids[1].b) {
            bvh__top_task x = kids[0];
            kids[0] = kids[1];
            kids[1] = x;
        }
        if (k >= 1) st[sp++] = kids[0];
        if (k == 2) st[sp++] = kids[1];
    }
}
#define BVH__TOP_TASKS 128
/* The threads take tasks from a queue, largest first: one larger than grain is split and its
   children queued, a smaller one is built whole. Which thread builds what varies; the tree does
   not (every task writes only its own nodes and clusters). A thread waits only while the queue
   is empty and another is busy with a task, which it ends without waiting: so a caller's pool
   may run these threads as tasks one after another (the first does all), and they need no
   barrier. Without pthreads, thread 0 does all. */
static void bvh__top_team_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    bvh__top_job *j = BVH__CAST(bvh__top_job *, arg);
    (void)team;
#ifdef BVH_NO_THREADS
    nt = 1;
#endif
    if (nt == 1) {
        uint32_t i;
        for (i = 0; tid == 0 && i < j->task_count; i++) bvh__top_subtree(j, &j->tasks[i]);
        return;
    }
#ifndef BVH_NO_THREADS
    pthread_mutex_lock(&j->mutex);
    for (;;) {
        bvh__top_task t, kids[2];
        uint32_t k = 0, i, big = 0;
        while (!j->task_count && j->busy) pthread_cond_wait(&j->cond, &j->mutex);
        if (!j->task_count) break;
        for (i = 1; i < j->task_count; i++)
            if (j->tasks[i].e - j->tasks[i].b > j->tasks[big].e - j->tasks[big].b) big = i;
        t = j->tasks[big];
        j->tasks[big] = j->tasks[--j->task_count];
        j->busy++;
        pthread_mutex_unlock(&j->mutex);
        if (t.e - t.b > j->grain)
            k = bvh__top_split(j, &t, kids);
        else
            bvh__top_subtree(j, &t);
        pthread_mutex_lock(&j->mutex);
        for (i = 0; i < k; i++) {
            if (j->task_count < BVH__TOP_TASKS) {
                j->tasks[j->task_count++] = kids[i];
                continue;
            }
            pthread_mutex_unlock(&j->mutex); /* full (not expected): build it here */
            bvh__top_subtree(j, &kids[i]);
            pthread_mutex_lock(&j->mutex);
        }
        j->busy--;
        pthread_cond_broadcast(&j->cond);
    }
    pthread_mutex_unlock(&j->mutex);
#endif
}
/* After the clustering, when the clusters once numbered top_m <= top_cut: builds a binned-SAH
   top over those clusters (the team takes tasks from a queue) and, when its summed node area is
   below that of PLOC's own top, writes it over src from top_slots on, in runs by height
   (children before parents), as bvh__emit expects. The tree does not depend on the thread count.
   Memory: PLOC's cin, cout and offers are free by then and hold the clusters, the top's nodes,
   both build buffers, the costs and (when they fit, as for n / 8 clusters) the integers, about
   44 bytes per cluster; else those are allocated. */
static bvh_result bvh__ploc_top(bvh__ploc *p, uint32_t nthreads) {
    const bvh__ctx *c = p->c;
    uint32_t m = p->top_m, base = p->top_slots, L = p->root - base + 1, i, h, H = 0, x, k = 0;
    uint32_t *height = NULL, *slot = NULL, *off = NULL, *par = NULL, *first = NULL, *cc = NULL, *lcc = NULL;
    uint32_t *leaf = NULL, *scratch = NULL;
    bvh_node *nodes = NULL;
    bvh__top_job jb, *job = &jb;
    bvh__top_task tasks[BVH__TOP_TASKS];
    double ploc_cost = 0.0, top_cost = 0.0, *cost;
    bvh_result r = BVH_SUCCESS;
    if (m < 3 || L != 2 * m - 1) return BVH_SUCCESS;
    /* Scratch: the nodes go to cin after the clusters, the costs to the offers' array; the
       3 m + 4 L + block_cap + 2 integers to cout after both build buffers when they fit there
       (they do for n / 8 clusters: memory the clustering has touched already), else allocated. */
    nodes = p->cin + m;
    cost = BVH__CAST(double *, (void *)p->best);
    {
        size_t need = 3 * (size_t)m + 4 * (size_t)L + p->block_cap + 2, room = ((size_t)c->n - 2 * (size_t)m) * 8;
        uint32_t *u = need <= room ? BVH__CAST(uint32_t *, (void *)(p->cout + 2 * (size_t)m)) : NULL;
        if (!u) u = scratch = BVH__ALLOC(&c->al, uint32_t, need);
        if (!u) {
            r = BVH_ERROR_OUT_OF_MEMORY;
            goto done;
        }
        height = u;
        slot = height + m;
        leaf = slot + m;
        par = leaf + m;
        first = par + L;
        cc = first + L;
        lcc = cc + L;
        off = lcc + L;
    }
    /* PLOC's top is src[base + x], x < L, children before parents: the m clusters are the
       entries made before the cut (or primitives), the others PLOC's nodes above them */
    for (x = 0; x < L; x++) {
        const bvh_node *s = &p->src[base + x];
        if (s->count || s->index < base) {
            cc[x] = 1;
            lcc[x] = 0;
        } else {
            uint32_t l = s->index - base;
            cc[x] = cc[l] + cc[l + 1];
            lcc[x] = cc[l];
            par[l] = par[l + 1] = x;
            ploc_cost += bvh__half_area_d(bvh__node_box(s));
        }
    }
    par[L - 1] = BVH__TOP_NONE;
    if (cc[L - 1] != m) goto done; /* cannot happen */
    /* clusters numbered left to right (copied to cin in that order, and to the build buffer
       with their number as index): every node's first from its parent's, root down */
    job->v[0] = p->cout;
    job->v[1] = p->cout + m;
    first[L - 1] = 0;
    for (x = L; x-- > 0;) {
        const bvh_node *s = &p->src[base + x];
        if (cc[x] == 1) {
            k = first[x];
            leaf[k] = x;
            p->cin[k] = *s;
            job->v[0][k] = *s;
            job->v[0][k].index = k;
        } else {
            uint32_t l = s->index - base;
            first[l] = first[x];
            first[l + 1] = first[x] + cc[l];
        }
    }
    job->par = par;
    job->first = first;
    job->cc = cc;
    job->lcc = lcc;
    job->leaf = leaf;
    job->nodes = nodes;
    job->tasks = tasks;
    job->task_count = 1;
    job->busy = 0;
    job->grain =
        m / (4 * nthreads) > BVH__MIN_PRIMS_PER_THREAD / 4 ? m / (4 * nthreads) : BVH__MIN_PRIMS_PER_THREAD / 4;
    tasks[0].id = 0;
    tasks[0].buf = 0;
    bvh__top_bounds(job->v[0], 0, m, &tasks[0]);
#ifndef BVH_NO_THREADS
    pthread_mutex_init(&job->mutex, NULL);
    pthread_cond_init(&job->cond, NULL);
#endif
    r = bvh__run(c, nthreads, 0, bvh__top_team_fn, job);
#ifndef BVH_NO_THREADS
    pthread_cond_destroy(&job->cond);
    pthread_mutex_destroy(&job->mutex);
#endif
    if (r != BVH_SUCCESS) goto done;
    for (i = m - 1; i-- > 0;) { /* children have larger ids: summed areas and heights from the last */
        uint32_t hh = 0;
        double sum = bvh__half_area_d(bvh__node_box(&nodes[i]));
        for (h = 0; h < 2; h++) {
            uint32_t y = h ? nodes[i].count : nodes[i].index;
            if (!(y & BVH__TOP_CLUSTER)) {
                sum += cost[y];
                if (height[y] > hh) hh = height[y];
            }
        }
        cost[i] = sum;
        height[i] = hh + 1;
        if (height[i] > H) H = height[i];
    }
    top_cost = cost[0];
    if (!(top_cost < ploc_cost) || p->top_blocks + H + 1 > p->block_cap) goto done;
    /* runs 1..H: pairs of the nodes of that height */
    for (h = 0; h <= H + 1; h++) off[h] = 0;
    for (i = 0; i < m - 1; i++) off[height[i]]++;
    {
        uint32_t at = p->top_slots;
        for (h = 1; h <= H; h++) {
            uint32_t pairs = off[h];
            off[h] = at;
            at += 2 * pairs;
            p->blocks[p->top_blocks + h - 1] = at;
        }
        p->root = at;
        p->blocks[p->top_blocks + H] = at + 1;
        p->block_count = p->top_blocks + H + 1;
    }
    for (i = 0; i < m - 1; i++) {
        slot[i] = off[height[i]];
        off[height[i]] += 2;
    }
    for (i = 0; i < m - 1; i++)
        for (h = 0; h < 2; h++) {
            uint32_t y = h ? nodes[i].count : nodes[i].index;
            bvh_node *d = &p->src[slot[i] + h];
            if (y & BVH__TOP_CLUSTER)
                *d = p->cin[y & ~BVH__TOP_CLUSTER];
            else {
                d->min = nodes[y].min;
                d->max = nodes[y].max;
                d->index = slot[y];
                d->count = 0;
            }
        }
    p->src[p->root].min = nodes[0].min;
    p->src[p->root].max = nodes[0].max;
    p->src[p->root].index = slot[0];
    p->src[p->root].count = 0;
done:
    bvh__free(&c->al, scratch);
    return r;
}

/* Memory: the clustering needs cin, cout, the node pairs (2n nodes) and the offers; it is run
   after the boxes and the sort's scratch are released, so that they are never all held at once
   (the peak: docs/DESIGN.md, Memory). */
static bvh_result bvh__build_ploc(bvh__ctx *c, bvh__out *o, uint32_t nthreads) {
    bvh__ploc p;
    bvh_result r;
    size_t n = c->n;
    memset(&p, 0, sizeof p);
    p.c = c;
    p.radius = c->radius;
    r = bvh__morton_job_init(c, &p.mj, nthreads);
    p.cin = BVH__ALLOC(&c->al, bvh_node, n);
    if (r == BVH_SUCCESS && !p.cin) r = BVH_ERROR_OUT_OF_MEMORY;
    bvh__stage_in(c->prog, 0.0f, 0.15f);
    if (r == BVH_SUCCESS)
        r = c->pool && nthreads > 1 ? bvh__ploc_init_steps(&p, nthreads)
                                    : bvh__run(c, nthreads, 1, bvh__ploc_init_fn, &p);
    bvh__stage_in(c->prog, 0.15f, 0.75f);
    /* the clusters now hold the boxes; the sorted keys' array becomes the offers' */
    bvh__free(&c->al, c->boxes);
    c->boxes = NULL;
    bvh__free(&c->al, p.mj.sort.keys_tmp);
    bvh__free(&c->al, p.mj.sort.vals_tmp);
    bvh__free(&c->al, p.mj.sort.hist);
    p.mj.sort.keys_tmp = NULL;
    p.mj.sort.vals_tmp = NULL;
    p.mj.sort.hist = NULL;
    p.best = p.mj.sort.keys;
    if (r == BVH_SUCCESS) {
        p.cout = BVH__ALLOC(&c->al, bvh_node, n);
        p.src = BVH__ALLOC(&c->al, bvh_node, 2 * n - 1);
        p.bnd = BVH__ALLOC(&c->al, uint64_t, (size_t)nthreads * p.radius);
        p.nn = BVH__ALLOC(&c->al, bvh__nn, nthreads);
        {
            size_t nbk = bvh__nn_block(n), cap = nbk + p.radius, t;
            p.nn_f = BVH__ALLOC(&c->al, float, (size_t)nthreads * 6 * cap);
            p.nn_i = BVH__ALLOC(&c->al, int32_t, (size_t)nthreads * (2 * nbk + 2 * cap));
            for (t = 0; p.nn && p.nn_f && p.nn_i && t < nthreads; t++) {
                float *f = p.nn_f + t * 6 * cap;
                int32_t *k = p.nn_i + t * (2 * nbk + 2 * cap);
                bvh__nn *w = &p.nn[t];
                w->lo[0] = f;
                w->lo[1] = f + cap;
                w->lo[2] = f + 2 * cap;
                w->hi[0] = f + 3 * cap;
                w->hi[1] = f + 4 * cap;
                w->hi[2] = f + 5 * cap;
                w->rd = k;
                w->rk = k + nbk;
                w->ld = k + 2 * nbk;
                w->lk = k + 2 * nbk + cap;
                w->block = nbk;
            }
        }
        p.role = BVH__ALLOC(&c->al, uint8_t, n);
        p.merges = BVH__ALLOC(&c->al, uint32_t, nthreads);
        p.survivors = BVH__ALLOC(&c->al, uint32_t, nthreads);
        p.block_cap = bvh__ploc_block_cap((uint32_t)n);
        p.blocks = BVH__ALLOC(&c->al, uint32_t, p.block_cap);
        p.top_cut = c->ploc_top ? (uint32_t)(n / c->ploc_top) : 0; /* 0: never */
        if (!p.cout || !p.src || !p.bnd || !p.nn || !p.nn_f || !p.nn_i || !p.role || !p.merges || !p.survivors ||
            !p.blocks)
            r = BVH_ERROR_OUT_OF_MEMORY;
    }
    /* under a pool, nthreads tasks per step (the clustering's buffers are per task) */
    if (r == BVH_SUCCESS)
        r = c->pool ? bvh__ploc_steps(&p, nthreads) : bvh__team_run(&c->al, nthreads, bvh__ploc_team_fn, &p);
    if (r == BVH_SUCCESS && p.stop) r = BVH_ERROR_CANCELLED;
    bvh__stage_in(c->prog, 0.75f, 1.0f);
    if (r == BVH_SUCCESS && bvh__report(c->prog, 0.0)) r = BVH_ERROR_CANCELLED;
    if (r == BVH_SUCCESS && p.top_m && p.block_count <= p.block_cap) r = bvh__ploc_top(&p, nthreads);
    /* release the clustering scratch before emission, which needs its own */
    bvh__free(&c->al, p.cin);
    bvh__free(&c->al, p.cout);
    bvh__free(&c->al, p.mj.sort.keys);
    bvh__free(&c->al, p.bnd);
    bvh__free(&c->al, p.nn);
    bvh__free(&c->al, p.nn_f);
    bvh__free(&c->al, p.nn_i);
    bvh__free(&c->al, p.role);
    bvh__free(&c->al, p.merges);
    bvh__free(&c->al, p.survivors);
    c->opt_done = 1; /* the optimizer, when asked for, runs here: before the collapse */
    if (r == BVH_SUCCESS && c->opt_rounds)
        r = bvh__optimize_emit(c, p.src, p.root, 2 * (uint32_t)n - 1, p.mj.sort.vals, 1, c->opt_threads, o);
    else if (r == BVH_SUCCESS)
        r = bvh__emit(c, p.src, p.root + 1, p.mj.sort.vals, 1, nthreads, p.block_count <= p.block_cap ? p.blocks : NULL,
                      p.block_count, o);
    bvh__free(&c->al, p.mj.sort.vals);
    bvh__free(&c->al, p.src);
    bvh__free(&c->al, p.blocks);
    return r;
}

/* ============================================================================================ */
/* == SAH-guided top-down with mid-point split partitioning ====================================== */
/* After Ganestam & Doggett 2016, as the study defines it: at every node and on each axis the
   mid-point plane of the node's bounds sorts the references into wholly left, wholly right and
   straddling; the straddlers are costed kept whole on their centroid's side (C_O) and clipped
   and referenced on both sides (C_S); the cheapest option wins unless a leaf costs no more.
   Invariants: a clipped part that only touches the plane is referenced on the other side only,
   so no leaf holds a primitive twice; at most split_budget * n extra references in all (the root
   gets the budget, a node shares what its split leaves between its children by size, a leaf's
   unused share goes to the next node depth-first); an object median is taken when no candidate
   separates the references or none is cheaper than not separating, and from the depth where
   halving is needed to stay within BVH_MAX_DEPTH. Added to the study (desc.sah_midpoint.bins;
   BVH_OFF = the study's variant): binned SAH object splits, C_S costed only where children
   overlap, reference unsplitting. Nodes come out depth-first, children adjacent and after their
   parent. On the build's threads: see "on the build's threads" below; the same tree for any
   count. The method in full, and the differences from the paper: docs/DESIGN.md. */
/* ============================================================================================ */
#ifndef BVH__SAH_MIDPOINT_ALPHA
#define BVH__SAH_MIDPOINT_ALPHA 1e-3
#endif
#define BVH__SM_MAX_BINS 64
/* pending tasks: at most one per level; median mode can reach depth 1 + log2(2^31) */
#define BVH__SM_STACK (BVH_MAX_DEPTH > 33 ? BVH_MAX_DEPTH + 4 : 37)

enum { BVH__SM_NONE, BVH__SM_BIN, BVH__SM_OVERLAP, BVH__SM_SPLIT, BVH__SM_MEDIAN };

typedef struct bvh__sm_ref {
    bvh_aabb box;
    uint32_t id;
} bvh__sm_ref; /* box: clipped bounds */

typedef struct bvh__sm_task {
    uint32_t node, count, depth; /* its references are work[top - count, top) when it is popped */
    uint32_t budget;             /* extra references this subtree may still create */
    uint32_t parent, right;      /* parallel builds: the parent's record (bvh__sm_rec), second child */
    uint32_t guess;              /* phase A: the budget if no subtree before it made duplicates */
    bvh_aabb box, cbox;          /* bounds of the references and of their centroids */
} bvh__sm_task;

typedef struct bvh__sm_choice {
    int kind, axis;
    uint32_t bin, bins, cut; /* BVH__SM_BIN: first child = slots below `bin` (see bvh__sm_axis) */
    float plane;             /* the mid-point of the chosen axis (the cut of the binning, or the plane) */
    float bin_lo, bin_scale;
    double cost;          /* C, the sum over both children of half-area * references */
    bvh_aabb left, right; /* BVH__SM_SPLIT: the children as costed, for unsplitting */
    uint32_t n_left, n_right;
} bvh__sm_choice;

typedef struct bvh__sm_par bvh__sm_par;
typedef struct bvh__sm {
    const bvh__ctx *c;
    bvh__sm_par *par; /* phase A of a parallel build: its passes over the references on the threads */
    bvh__out *o;
    bvh__sm_ref *work;
    uint32_t top, cap, budget, extra, carry, node_max, bins;
    int tight;       /* a comparison with the budget decided something: more budget might change it */
    uint32_t lo, hi; /* the node's decisions are the same for any budget in [lo, hi] */
    uint32_t room;   /* at most this many duplicates in all (a subtree's slot), else overflow */
    int overflow;    /* a duplicate was not made for want of room: the result is not used */
    uint32_t *cons;  /* NULL, or per node: lo, hi, first child's references, duplicates */
    double root_area;
    /* evaluation scratch, per axis */
    bvh_aabb bin[3][BVH__SM_MAX_BINS + 1]; /* one more: the bin holding the mid-point, cut */
    uint32_t bin_n[3][BVH__SM_MAX_BINS + 1];
    double right_area[BVH__SM_MAX_BINS + 1];
    uint32_t right_n[BVH__SM_MAX_BINS + 1];
} bvh__sm;

/* Halving is exact (but for subnormals), so even a contracted (FMA) form gives the same value:
   every pass bins a reference alike. (Not bvh__centroid, which adds first: the two differ
   where the sum overflows or a half is subnormal.) */
BVH__INLINE float bvh__sm_centre(const bvh__sm_ref *r, int a) {
    return 0.5f * bvh__at(&r->box.min, a) + 0.5f * bvh__at(&r->box.max, a);
}
BVH__INLINE bvh_vec3 bvh__sm_centroid(const bvh__sm_ref *r) {
    bvh_vec3 c;
    c.x = bvh__sm_centre(r, 0);
    c.y = bvh__sm_centre(r, 1);
    c.z = bvh__sm_centre(r, 2);
    return c;
}
BVH__INLINE uint32_t bvh__sm_bin_of(float x, float lo, float scale, uint32_t bins) {
    /* (x - lo) * scale >= 0, +inf when the centroid range overflows float: clamp, then convert */
    float f = bvh__minf((x - lo) * scale, (float)(bins - 1));
    return (uint32_t)(int)f;
}
static uint32_t bvh__sm_log2(uint32_t m) { /* ceil(log2(m)) */
    uint32_t l = 0;
    while (l < 32 && ((uint64_t)1 << l) < m) l++;
    return l;
}
static float bvh__sm_to_float(double x) { return x < -FLT_MAX ? -FLT_MAX : x > FLT_MAX ? FLT_MAX : (float)x; }

/* Bounds of the parts of reference r (which straddles x[a] = p) on each side of the plane: bit 0
   of the result when *l holds a non-empty left part, bit 1 for *rt and the right part. Triangles
   are clipped in double; points on the plane get p exactly on axis a, and on the other axes are
   widened by (|u| + |v|) 2^-21, far more than the error of the double computation and of the
   rounding to float, so the boxes stay conservative. */
static int bvh__sm_clip(const bvh__ctx *c, const bvh__sm_ref *r, int a, float p, bvh__sm_ref *l, bvh__sm_ref *rt) {
    float t[9];
    float llo[3], lhi[3], rlo[3], rhi[3];
    int e, k, mask = 0;
    *l = *r;
    *rt = *r;
    if (!c->tris) {
        bvh__set(&l->box.max, a, p);
        bvh__set(&rt->box.min, a, p);
        return 3;
    }
    bvh__ctx_triangle(c, r->id, t);
    for (k = 0; k < 3; k++) {
        llo[k] = rlo[k] = BVH_INF;
        lhi[k] = rhi[k] = -BVH_INF;
    }
    for (e = 0; e < 3; e++) {
        const float *u = t + 3 * e, *v = t + 3 * (e == 2 ? 0 : e + 1);
        if (u[a] <= p)
            for (k = 0; k < 3; k++) {
                llo[k] = bvh__minf(llo[k], u[k]);
                lhi[k] = bvh__maxf(lhi[k], u[k]);
            }
        if (u[a] >= p)
            for (k = 0; k < 3; k++) {
                rlo[k] = bvh__minf(rlo[k], u[k]);
                rhi[k] = bvh__maxf(rhi[k], u[k]);
            }
        if ((u[a] < p && v[a] > p) || (u[a] > p && v[a] < p)) {
            double f = ((double)p - u[a]) / ((double)v[a] - u[a]);
            for (k = 0; k < 3; k++) {
                double x, eps;
                float xl, xh;
                if (k == a) {
                    xl = xh = p;
                } else {
                    x = u[k] + f * ((double)v[k] - u[k]);
                    eps = (fabs((double)u[k]) + fabs((double)v[k])) * (1.0 / 2097152.0) + (double)FLT_MIN;
                    xl = bvh__sm_to_float(x - eps);
                    xh = bvh__sm_to_float(x + eps);
                }
                llo[k] = bvh__minf(llo[k], xl);
                lhi[k] = bvh__maxf(lhi[k], xh);
                rlo[k] = bvh__minf(rlo[k], xl);
                rhi[k] = bvh__maxf(rhi[k], xh);
            }
        }
    }
    for (k = 0; k < 3; k++) {
        bvh__set(&l->box.min, k, bvh__maxf(llo[k], bvh__at(&r->box.min, k)));
        bvh__set(&l->box.max, k, bvh__minf(lhi[k], bvh__at(&r->box.max, k)));
        bvh__set(&rt->box.min, k, bvh__maxf(rlo[k], bvh__at(&r->box.min, k)));
        bvh__set(&rt->box.max, k, bvh__minf(rhi[k], bvh__at(&r->box.max, k)));
    }
    bvh__set(&l->box.max, a, bvh__minf(bvh__at(&l->box.max, a), p));
    bvh__set(&rt->box.min, a, bvh__maxf(bvh__at(&rt->box.min, a), p));
    if (bvh__nonempty(l->box) && bvh__at(&l->box.min, a) < p) mask |= 1;
    if (bvh__nonempty(rt->box) && bvh__at(&rt->box.max, a) > p) mask |= 2;
    if (!mask) { /* cannot happen with conservative boxes; keep the whole reference on one side */
        *l = *r;
        *rt = *r;
        mask = bvh__sm_centre(r, a) < p ? 1 : 2;
    }
    return mask;
}

/* Half area of the intersection of two boxes (0 when they do not overlap). */
static double bvh__sm_overlap(const bvh_aabb *x, const bvh_aabb *y) {
    bvh_aabb i;
    i.min.x = bvh__maxf(x->min.x, y->min.x);
    i.min.y = bvh__maxf(x->min.y, y->min.y);
    i.min.z = bvh__maxf(x->min.z, y->min.z);
    i.max.x = bvh__minf(x->max.x, y->max.x);
    i.max.y = bvh__minf(x->max.y, y->max.y);
    i.max.z = bvh__minf(x->max.z, y->max.z);
    return bvh__half_area_d(i);
}
static int bvh__sm_offer(bvh__sm_choice *best, int kind, int axis, float plane, double cost) {
    if (best->kind != BVH__SM_NONE && !(cost < best->cost)) return 0; /* ties: the earlier candidate */
    best->kind = kind;
    best->axis = axis;
    best->plane = plane;
    best->cost = cost;
    return 1;
}

/* Binning of one axis: `bins` bins over the centroid bounds (1 when not binning), and when the
   mid-point p lies within the centroid bounds, bin kp (the one holding p) cut in two at p: its
   references left of p stay in slot kp, the others move up one slot with every later bin. The
   boundary below slot kp + 1 then separates exactly D_L u O_L from D_R u O_R (left: centroid < p,
   or centroid = p with the box not beyond p), so C_O is one candidate of the sweep. */
typedef struct bvh__sm_axis {
    float lo, scale, p;
    uint32_t bins, kp; /* kp = bins: no cut */
} bvh__sm_axis;
BVH__INLINE uint32_t bvh__sm_slot(const bvh__sm_ref *r, int a, float c, const bvh__sm_axis *x) { /* c: centroid */
    uint32_t k = x->bins > 1 ? bvh__sm_bin_of(c, x->lo, x->scale, x->bins) : 0;
    uint32_t right =
        (uint32_t)(c >= x->p) & (uint32_t)((c != x->p) | (bvh__at(&r->box.max, a) > x->p)); /* not in D_L u O_L */
    return k + (uint32_t)(k > x->kp) + ((uint32_t)(k == x->kp) & right);
}

/* Pass 2's sums per axis: the references wholly left and right of the plane, the straddlers'
   clipped parts on each side, the straddlers referenced on both; over: more of those than the
   budget (the rest of the range was not looked at). Boxes merge by min and max and counts add,
   so the sums of a node cut into ranges are the same in any order. */
typedef struct bvh__sm_sums {
    bvh_aabb dl[3], dr[3], sl[3], sr[3];
    uint32_t ndl[3], ndr[3], nsl[3], nsr[3], dup[3];
    int over[3];
} bvh__sm_sums;
typedef bvh_aabb bvh__sm_bins[3][BVH__SM_MAX_BINS + 1];
typedef uint32_t bvh__sm_counts[3][BVH__SM_MAX_BINS + 1];

/* Pass 1 over work[i, e): the slots of every axis that has two or more, cleared first. */
BVH__INLINE void bvh__sm_pass1(const bvh__sm_ref *w, uint32_t i, uint32_t e, const bvh__sm_axis *x,
                               const uint32_t *slots, bvh__sm_bins bin, bvh__sm_counts bin_n) {
    uint32_t k;
    int a;
    for (a = 0; a < 3; a++)
        for (k = 0; k < slots[a]; k++) {
            bin[a][k] = bvh__empty();
            bin_n[a][k] = 0;
        }
    for (; i < e; i++) {
        const bvh__sm_ref *r = &w[i];
        for (a = 0; a < 3; a++) {
            if (slots[a] < 2) continue;
            k = bvh__sm_slot(r, a, bvh__sm_centre(r, a), &x[a]);
            bin[a][k] = bvh__merge(bin[a][k], r->box);
            bin_n[a][k]++;
        }
    }
}
/* Pass 2 over work[i, e) for the axes of clip[]. */
BVH__INLINE void bvh__sm_pass2(const bvh__ctx *c, const bvh__sm_ref *w, uint32_t i, uint32_t e, const bvh__sm_axis *x,
                               const int *clip_in, uint32_t budget, bvh__sm_sums *u) {
    int clip[3], a;
    for (a = 0; a < 3; a++) {
        clip[a] = clip_in[a];
        u->dl[a] = u->dr[a] = u->sl[a] = u->sr[a] = bvh__empty();
        u->ndl[a] = u->ndr[a] = u->nsl[a] = u->nsr[a] = u->dup[a] = 0;
        u->over[a] = 0;
    }
    for (; i < e; i++) {
        const bvh__sm_ref *r = &w[i];
        for (a = 0; a < 3; a++) {
            bvh__sm_ref lp, rp;
            int mask;
            float p = x[a].p;
            if (!clip[a]) continue;
            if (bvh__at(&r->box.max, a) <= p) {
                u->dl[a] = bvh__merge(u->dl[a], r->box);
                u->ndl[a]++;
                continue;
            }
            if (bvh__at(&r->box.min, a) >= p) {
                u->dr[a] = bvh__merge(u->dr[a], r->box);
                u->ndr[a]++;
                continue;
            }
            mask = bvh__sm_clip(c, r, a, p, &lp, &rp);
            if (mask & 1) {
                u->sl[a] = bvh__merge(u->sl[a], lp.box);
                u->nsl[a]++;
            }
            if (mask & 2) {
                u->sr[a] = bvh__merge(u->sr[a], rp.box);
                u->nsr[a]++;
            }
            if (mask == 3 && ++u->dup[a] > budget) { /* over budget: not a candidate */
                clip[a] = 0;
                u->over[a] = 1;
            }
        }
    }
}
/* Phase A: a pass over work[b, b + m) on the build's threads, merged into s->bin or *sums;
   0 when the threads could not be had (then the caller makes the pass). */
static int bvh__sm_pass_team(bvh__sm *s, int pass, uint32_t b, uint32_t m, uint32_t budget, const bvh__sm_axis *x,
                             const uint32_t *slots, const int *clip, bvh__sm_sums *sums);

/* Costs every candidate of the node work[b, b + m) with bounds nb and centroid bounds cb, allowed
   `budget` duplicates; *best gets the cheapest (BVH__SM_NONE when nothing separates). Pass 1 bins
   the references (C_O and the object splits come out of one sweep per axis); pass 2 sorts them
   into D_L, D_R and straddlers and clips the straddlers for C_S. With bins, pass 2 runs only
   where the best candidate so far has children overlapping by more than BVH__SAH_MIDPOINT_ALPHA
   of the root's area; without bins (the study's variant) C_S is always costed. */
static void bvh__sm_evaluate(bvh__sm *s, uint32_t b, uint32_t m, uint32_t budget, const bvh_aabb *nb,
                             const bvh_aabb *cb, bvh__sm_choice *best) {
    const uint32_t bins = s->bins < m ? s->bins : m; /* small nodes: fewer bins */
    bvh__sm_axis x[3];
    bvh__sm_sums u;
    bvh_aabb lb, rb;
    uint32_t slots[3], k, best_slot = 0;
    int mid_ok[3], clip[3], any_clip = 0, a;
    best->kind = BVH__SM_NONE;
    best->cost = 0.0;
    for (a = 0; a < 3; a++) {
        bvh__sm_axis *xa = &x[a];
        const float nlo = bvh__at(&nb->min, a), nhi = bvh__at(&nb->max, a);
        const float clo = bvh__at(&cb->min, a), chi = bvh__at(&cb->max, a);
        xa->p = 0.5f * nlo + 0.5f * nhi;
        mid_ok[a] = nlo < xa->p && xa->p < nhi;
        xa->lo = clo;
        xa->bins = bins > 1 && clo < chi ? bins : 1;
        xa->scale = xa->bins > 1 ? (float)((double)bins / ((double)chi - clo)) : 0.0f;
        if (xa->bins > 1 && !(xa->scale > 0.0f && xa->scale <= FLT_MAX)) {
            xa->bins = 1;
            xa->scale = 0.0f;
        }
        xa->kp = xa->bins;
        if (mid_ok[a] && clo <= xa->p && xa->p <= chi)
            xa->kp = xa->bins > 1 ? bvh__sm_bin_of(xa->p, xa->lo, xa->scale, xa->bins) : 0;
        slots[a] = xa->bins + (xa->kp < xa->bins);
    }
    if (!s->par || !bvh__sm_pass_team(s, 1, b, m, budget, x, slots, NULL, NULL))
        bvh__sm_pass1(s->work, b, b + m, x, slots, s->bin, s->bin_n);
    for (a = 0; a < 3; a++) { /* Wald 2007: sweep the slots from the right, then from the left */
        bvh_aabb acc;
        uint32_t n = 0;
        double area = 0.0;
        if (slots[a] < 2) continue;
        acc = bvh__empty();
        for (k = slots[a] - 1; k > 0; k--) { /* an empty slot changes nothing: no area to compute */
            if (s->bin_n[a][k]) {
                acc = bvh__merge(acc, s->bin[a][k]);
                n += s->bin_n[a][k];
                area = bvh__half_area_d(acc);
            }
            s->right_area[k] = area;
            s->right_n[k] = n;
        }
        acc = bvh__empty();
        n = 0;
        for (k = 1; k < slots[a]; k++) { /* after an empty slot the candidate repeats the previous one */
            if (!s->bin_n[a][k - 1]) continue;
            acc = bvh__merge(acc, s->bin[a][k - 1]);
            n += s->bin_n[a][k - 1];
            if (!s->right_n[k]) break;
            if (bvh__sm_offer(best, k == x[a].kp + 1 ? BVH__SM_OVERLAP : BVH__SM_BIN, a, x[a].p,
                              bvh__half_area_d(acc) * n + s->right_area[k] * s->right_n[k]))
                best_slot = k;
        }
    }
    if (best->kind == BVH__SM_BIN) {
        const bvh__sm_axis *xa = &x[best->axis];
        best->bin = best_slot;
        best->bins = xa->bins;
        best->cut = xa->kp;
        best->bin_lo = xa->lo;
        best->bin_scale = xa->scale;
    }
    /* C_S: does a split have anything to gain? */
    {
        int gate = s->bins > 0 && best->kind != BVH__SM_NONE;
        if (gate) {
            a = best->axis;
            lb = bvh__empty();
            rb = bvh__empty();
            for (k = 0; k < slots[a]; k++) {
                bvh_aabb *side = k < best_slot ? &lb : &rb;
                *side = bvh__merge(*side, s->bin[a][k]);
            }
            gate = !(bvh__sm_overlap(&lb, &rb) > BVH__SAH_MIDPOINT_ALPHA * s->root_area);
        }
        for (a = 0; a < 3; a++) {
            clip[a] = !gate && budget > 0 && mid_ok[a];
            if (!gate && mid_ok[a] && budget == 0) { /* clipping was wanted: more budget may choose it */
                s->tight = 1;
                s->hi = 0;
            }
            any_clip |= clip[a];
        }
    }
    if (!any_clip) return;
    if (!s->par || !bvh__sm_pass_team(s, 2, b, m, budget, x, slots, clip, &u))
        bvh__sm_pass2(s->c, s->work, b, b + m, x, clip, budget, &u);
    for (a = 0; a < 3; a++) {
        if (!clip[a]) continue;
        if (u.over[a] || u.dup[a] > budget) { /* over budget: not a candidate (more budget may choose it) */
            s->tight = 1;
            if (s->hi > budget) s->hi = budget;
            continue;
        }
        if (!(u.nsl[a] + u.nsr[a]) || !(u.ndl[a] + u.nsl[a]) || !(u.ndr[a] + u.nsr[a])) continue;
        lb = u.dl[a];
        lb = bvh__merge(lb, u.sl[a]);
        rb = u.dr[a];
        rb = bvh__merge(rb, u.sr[a]);
        if (bvh__sm_offer(best, BVH__SM_SPLIT, a, x[a].p,
                          bvh__half_area_d(lb) * (u.ndl[a] + u.nsl[a]) +
                              bvh__half_area_d(rb) * (u.ndr[a] + u.nsr[a]))) {
            best->left = lb;
            best->right = rb;
            best->n_left = u.ndl[a] + u.nsl[a];
            best->n_right = u.ndr[a] + u.nsr[a];
        }
    }
    /* less budget changes the choice only where it refuses the winner (a loser refused is no loss) */
    if (best->kind == BVH__SM_SPLIT) {
        const uint32_t need = u.dup[best->axis] > 1 ? u.dup[best->axis] : 1;
        if (s->lo < need) s->lo = need;
    }
}

BVH__INLINE void bvh__sm_swap(bvh__sm_ref *x, bvh__sm_ref *y) {
    bvh__sm_ref t = *x;
    *x = *y;
    *y = t;
}

/* Grows a child's bounds and centroid bounds by reference r. */
BVH__INLINE void bvh__sm_add(bvh__sm_task *t, const bvh__sm_ref *r, bvh_vec3 centroid) {
    t->box = bvh__merge(t->box, r->box);
    bvh__grow(&t->cbox, centroid);
}
/* Reference unsplitting (Stich, Friedrich & Dietrich 2009, Sec. 4.4), with bins only: keeps a
   straddler whole on one side when that costs less than referencing it on both, judged against
   the children as costed. Returns 1 (left), 2 (right) or 3 (split). */
static int bvh__sm_unsplit(const bvh__sm_choice *ch, const bvh__sm_ref *r) {
    bvh_aabb l = ch->left, rt = ch->right;
    double al = bvh__half_area_d(ch->left), ar = bvh__half_area_d(ch->right), split, c1, c2;
    split = al * ch->n_left + ar * ch->n_right;
    l = bvh__merge(l, r->box);
    rt = bvh__merge(rt, r->box);
    c1 = bvh__half_area_d(l) * ch->n_left + ar * (ch->n_right - 1);
    c2 = al * (ch->n_left - 1) + bvh__half_area_d(rt) * ch->n_right;
    if (c1 < split && c1 <= c2) return 1;
    if (c2 < split) return 2;
    return 3;
}

/* Partitions the node's references work[b, top): the first child's go to the top of the work
   array (it is processed first), the second child's below them, and their bounds into *first and
   *second. Split references get their right part in place and their left part appended at the
   top (at most `budget` of them). Returns the first child's count; s->top counts the duplicates. */
static uint32_t bvh__sm_partition(bvh__sm *s, uint32_t b, uint32_t budget, const bvh__sm_choice *ch,
                                  bvh__sm_task *first, bvh__sm_task *second) {
    bvh__sm_ref *w = s->work;
    uint32_t top = s->top, i = b, j = top;
    if (ch->kind == BVH__SM_SPLIT) { /* three-way: [right only | both (right part) | left only] + left parts */
        uint32_t lo = b, mid = b, hi = top, dups = 0;
        int a = ch->axis;
        float p = ch->plane;
        while (mid < hi) {
            bvh__sm_ref *r = &w[mid];
            int side; /* 1 left, 2 right, 3 both */
            if (bvh__at(&r->box.max, a) <= p)
                side = 1;
            else if (bvh__at(&r->box.min, a) >= p)
                side = 2;
            else {
                bvh__sm_ref lp, rp;
                int mask = bvh__sm_clip(s->c, r, a, p, &lp, &rp);
                if (mask != 3) {
                    side = mask;
                    *r = mask == 1 ? lp : rp;
                } /* touches one side only */
                else {
                    side = s->bins ? bvh__sm_unsplit(ch, r) : 3; /* 1 or 2: whole, on that side */
                    if (side == 3 && (dups >= budget || s->extra + dups >= s->room)) {
                        side = bvh__sm_centre(r, a) < p ? 1 : 2;
                        if (dups < budget)
                            s->overflow = 1;
                        else { /* this budget only */
                            s->tight = 1;
                            if (s->lo < budget) s->lo = budget;
                            if (s->hi > budget) s->hi = budget;
                        }
                    }
                    if (side == 3) {
                        w[top + dups++] = lp;
                        *r = rp;
                        bvh__sm_add(first, &lp, bvh__sm_centroid(&lp));
                    }
                }
            }
            bvh__sm_add(side == 1 ? first : second, r, bvh__sm_centroid(r));
            if (side == 2) {
                bvh__sm_swap(&w[lo], &w[mid]);
                lo++;
                mid++;
            } else if (side == 3)
                mid++;
            else {
                hi--;
                bvh__sm_swap(&w[mid], &w[hi]);
            }
        }
        if (s->lo < dups) s->lo = dups;
        s->extra += dups;
        s->top = top + dups;
        return s->top - mid;
    }
    { /* two-way, binned (slots below ch->bin) or C_O (D_L u O_L) */
        const int a = ch->axis, binned = ch->kind == BVH__SM_BIN;
        const float p = ch->plane;
        bvh__sm_axis x;
        x.lo = ch->bin_lo;
        x.scale = ch->bin_scale;
        x.p = p;
        x.bins = ch->bins;
        x.kp = ch->cut;
        while (i < j) {
            const bvh__sm_ref *r = &w[i];
            const bvh_vec3 cc = bvh__sm_centroid(r);
            const float ca = bvh__at(&cc, a);
            int go_first;
            if (binned)
                go_first = bvh__sm_slot(r, a, ca, &x) < ch->bin;
            else
                go_first = bvh__at(&r->box.max, a) <= p || (bvh__at(&r->box.min, a) < p && ca < p);
            bvh__sm_add(go_first ? first : second, r, cc);
            if (!go_first)
                i++;
            else {
                j--;
                bvh__sm_swap(&w[i], &w[j]);
            }
        }
    }
    return top - i;
}

static float bvh__sm_key(const void *ctx, const void *e, int axis) {
    (void)ctx;
    return bvh__sm_centre(BVH__CAST(const bvh__sm_ref *, e), axis);
}
/* Object median on the longest centroid axis; returns the first child's count (the upper half). */
static uint32_t bvh__sm_median(bvh__sm *s, uint32_t b, uint32_t m, const bvh_aabb *cb) {
    int axis = bvh__median_axis(*cb);
    if (axis >= 0) bvh__select(s->work + b, sizeof *s->work, m, m / 2, bvh__sm_key, NULL, axis);
    return m - m / 2;
}

static void bvh__sm_bounds(const bvh__sm_ref *v, uint32_t n, bvh_aabb *box, bvh_aabb *cbox) {
    uint32_t i;
    *box = bvh__empty();
    *cbox = bvh__empty();
    for (i = 0; i < n; i++) {
        *box = bvh__merge(*box, v[i].box);
        bvh__grow(cbox, bvh__sm_centroid(&v[i]));
    }
}

static bvh_result bvh__sm_reserve_pair(bvh__sm *s) {
    bvh__out *o = s->o;
    bvh_node *nodes;
    uint64_t cap;
    if (o->node_count + 2 <= o->node_cap) return BVH_SUCCESS;
    cap = (uint64_t)o->node_cap + o->node_cap / 2 + 1024;
    if (cap > s->node_max) cap = s->node_max;
    if (cap < (uint64_t)o->node_count + 2) return BVH_ERROR_OUT_OF_MEMORY; /* cannot happen: 2 refs - 1 */
    nodes = BVH__ALLOC(&s->c->al, bvh_node, cap);
    if (!nodes) return BVH_ERROR_OUT_OF_MEMORY;
    memcpy(nodes, o->nodes, (size_t)o->node_count * sizeof(bvh_node));
    bvh__free(&s->c->al, o->nodes);
    o->nodes = nodes;
    o->node_cap = (uint32_t)cap;
    return BVH_SUCCESS;
}

/* Decides node t, whose references are work[top - t->count, top) and whose budget includes the
   carry: ch->kind BVH__SM_NONE makes it a leaf, anything else says how to split it. */
static void bvh__sm_decide(bvh__sm *s, const bvh__sm_task *t, bvh__sm_choice *ch) {
    const bvh__ctx *c = s->c;
    const uint32_t m = t->count, b = s->top - m;
    memset(ch, 0, sizeof *ch);
    ch->kind = BVH__SM_MEDIAN;
    if (!bvh__fits_depth(t->depth, bvh__sm_log2(m) + 5)) { /* halve from here on: depth stays bounded */
        if (m <= c->max_leaf) ch->kind = BVH__SM_NONE;
    } else if (m <= 1) {
        ch->kind = BVH__SM_NONE;
    } else {
        double area = bvh__half_area_d(t->box), split;
        bvh__sm_evaluate(s, b, m, t->budget, &t->box, &t->cbox, ch);
        /* E_r = C_i A(n) + C_t C; where nothing separates, a leaf whenever one may hold them */
        split = ch->kind == BVH__SM_NONE ? HUGE_VAL : c->ci * area + c->ct * ch->cost;
        if (bvh__sah_leaf(c, m, BVH__LEAF_COST(c, area, (double)m), split)) {
            ch->kind = BVH__SM_NONE; /* leaf: E_t <= E_r */
            s->lo = 0;               /* refusing the winner for want of budget leaves a dearer split: a leaf still */
        } else if (ch->kind == BVH__SM_NONE || !(ch->cost < area * m))
            ch->kind = BVH__SM_MEDIAN;
    }
}

/* Splits node t as ch says: the children's references end on top of the work array (the first
   child's above the second's), their counts, bounds, depth and budgets in *tl and *tr (the
   budget the split leaves is shared by size). Returns the duplicates the split made. */
static uint32_t bvh__sm_children(bvh__sm *s, const bvh__sm_task *t, const bvh__sm_choice *ch, bvh__sm_task *tl,
                                 bvh__sm_task *tr) {
    const uint32_t m = t->count, b = s->top - m;
    uint32_t nl, nr, left;
    tl->box = tl->cbox = tr->box = tr->cbox = bvh__empty();
    nl = ch->kind == BVH__SM_MEDIAN ? 0 : bvh__sm_partition(s, b, t->budget, ch, tl, tr);
    if (nl == 0 || nl == s->top - b) { /* median (no duplicates were made) */
        nl = bvh__sm_median(s, b, m, &t->cbox);
        bvh__sm_bounds(s->work + s->top - nl, nl, &tl->box, &tl->cbox);
        bvh__sm_bounds(s->work + b, s->top - b - nl, &tr->box, &tr->cbox);
    }
    nr = s->top - b - nl;
    left = t->budget - (s->top - b - m); /* shared by the children in proportion to their size */
    tl->budget = (uint32_t)((uint64_t)left * nl / (nl + nr));
    tr->budget = left - tl->budget;
    tl->count = nl;
    tr->count = nr;
    tl->depth = tr->depth = t->depth + 1;
    return s->top - b - m;
}

/* Builds the subtrees of the tasks on the stack, depth-first, into s->o: a node's children are
   the next free pair when it is split, a leaf's references the next in s->o->refs. `prog`: NULL
   on the threads of a parallel build (the calling thread reports between their rounds). */
static bvh_result bvh__sm_run(bvh__sm *s, bvh__sm_task *stack, uint32_t sp, bvh__progress *prog) {
    bvh__out *o = s->o;
    uint32_t i;
    bvh_result r;
    while (sp) {
        bvh__sm_task t = stack[--sp], tl, tr;
        uint32_t m = t.count, b = s->top - m;
        bvh__sm_choice ch;
        bvh_aabb box;
        bvh_node *node;
        if (prog && bvh__tick(prog, m, (double)o->ref_count / (double)s->cap)) return BVH_ERROR_CANCELLED;
        t.budget += s->carry; /* what the subtrees before this one left unused */
        s->carry = 0;
        s->lo = 0;
        s->hi = 0xffffffffu;
        bvh__sm_decide(s, &t, &ch);
        node = &o->nodes[t.node];
        if (ch.kind == BVH__SM_NONE) { /* leaf */
            bvh__set_box(node, t.box);
            node->index = o->ref_count;
            node->count = m;
            for (i = b; i < b + m; i++) o->refs[o->ref_count++] = s->work[i].id;
            s->top = b;
            s->carry = t.budget;
            if (s->cons) {
                uint32_t *k = s->cons + 4 * (size_t)t.node;
                k[0] = s->lo;
                k[1] = s->hi;
                k[2] = k[3] = 0;
            }
            continue;
        }
        i = bvh__sm_children(s, &t, &ch, &tl, &tr);
        if (s->cons) {
            uint32_t *k = s->cons + 4 * (size_t)t.node;
            k[0] = s->lo;
            k[1] = s->hi;
            k[2] = tl.count;
            k[3] = i;
        }
        r = bvh__sm_reserve_pair(s);
        if (r != BVH_SUCCESS) return r;
        node = &o->nodes[t.node];
        tl.node = o->node_count;
        tr.node = o->node_count + 1;
        o->node_count += 2;
        box = tl.box;
        box = bvh__merge(box, tr.box); /* split parts may be tighter than the node's references */
        bvh__set_box(node, box);
        node->index = tl.node;
        node->count = 0;
        BVH_ASSERT(sp + 2 <= BVH__SM_STACK);
        stack[sp++] = tr;
        stack[sp++] = tl;
    }
    return BVH_SUCCESS;
}

/* == on the build's threads ==
   Phase A splits the nodes of at least `threshold` references on the calling thread, in the
   serial order, and leaves the smaller ones (copied out of the work array) as subtrees that the
   threads then build in any order, each into its own slot of an arena; the assembly numbers the
   nodes and references in the serial order. The tree is the serial one if every node sees the
   serial budget. Its one serial dependency is the carry: a subtree's unused budget goes to the
   node after it. Phase A takes 0 for the carry of a subtree not yet built (a lower bound:
   budgets only grow with it, and both children's shares grow with their parent's); a decision
   that no comparison with the budget made (s->tight clear) is the one any larger budget makes,
   and a node of phase A that compared with an inexact budget makes the build start again
   serially. A subtree is built with a guess (the budget if no subtree before it made
   duplicates: most of the budget is left unused and flows on) and records, per node, the range
   of budgets that make the same decisions; the assembly walks the nodes in order with the exact
   budgets, checks every node of a subtree against its range, and builds again, on the calling
   thread, a subtree whose check fails or that had not the room for its duplicates (its slot is
   sized for the lower bound). */
typedef struct bvh__sm_rec {
    uint32_t parent, right; /* the parent's record (BVH_INVALID: the root), 1: the second child */
    uint32_t sub;           /* its subtree, or BVH_INVALID: a node phase A split */
    uint32_t budget;        /* phase A: the budget it was split with; the exact one after assembly */
    uint32_t dups, nl, nr;  /* phase A: duplicates the split made, the children's references */
    uint32_t base;          /* phase A: its children's index (assembly) */
    bvh_aabb box;
} bvh__sm_rec;
typedef struct bvh__sm_sub {
    bvh__sm_task t;                  /* budget: the lower bound (its slot's room for duplicates) */
    uint32_t in;                     /* its references: par->in[in, in + t.count) */
    uint32_t node_off, ref_off;      /* its slot of the arena (and of par->cons) */
    uint32_t built;                  /* the budget it was built with (t.guess, then the exact one) */
    uint32_t nodes, refs, dups;      /* what it made */
    uint32_t g, node_base, ref_base; /* assembly: its root's index, where its nodes and refs go */
    int overflow, own;               /* own: built again into blocks of its own */
    bvh_node *out_nodes;
    uint32_t *out_refs;
} bvh__sm_sub;
struct bvh__sm_par {
    bvh__sm *s;                /* phase A's (the build's work array) */
    bvh__sm *ts;               /* one per thread (in phase A, their bins are the threads' pass 1) */
    bvh__sm_sums *sums;        /* phase A: the threads' pass 2 */
    bvh__sm_ref *in, *scratch; /* the subtrees' references; per thread, room for the largest */
    bvh__sm_rec *rec;
    bvh__sm_sub *sub;
    uint32_t *order; /* the subtrees, largest first */
    bvh_node *arena_nodes;
    uint32_t *arena_refs, *cons; /* cons: the subtrees' nodes' ranges (bvh__sm.cons) */
    uint32_t nt, threshold, in_used, nrec, rec_cap, nsub, sub_cap, pending, scratch_cap;
    size_t next, end; /* the next subtree of `order` no thread has taken, the end of the round */
    int oom;          /* phase A: a pass could not have its threads */
    bvh__out *out;    /* the assembly's */
};
#define BVH__SM_FALLBACK ((bvh_result)-1000) /* internal: phase A needs an exact budget */
#ifndef BVH__SM_EVENT /* private; the tests count the rare paths: BVH__SM_EVENT(rebuilt), (serial) */
#define BVH__SM_EVENT(what) ((void)0)
#endif

static int bvh__sm_grow(const bvh__ctx *c, void **p, uint32_t *cap, uint32_t used, size_t size) {
    void *q;
    uint32_t n;
    if (used < *cap) return 1;
    n = *cap ? 2 * *cap : 64;
    if (!(q = bvh__alloc(&c->al, n, size))) return 0;
    if (used) memcpy(q, *p, (size_t)used * size);
    bvh__free(&c->al, *p);
    *p = q;
    *cap = n;
    return 1;
}

typedef struct bvh__sm_pass_job {
    bvh__sm_par *par;
    const bvh__sm *s;
    int pass;
    uint32_t b, m, budget, used; /* used: the threads the team had */
    const bvh__sm_axis *x;
    const uint32_t *slots;
    const int *clip;
} bvh__sm_pass_job;
static void bvh__sm_pass_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    bvh__sm_pass_job *j = BVH__CAST(bvh__sm_pass_job *, arg);
    size_t lo, hi;
    (void)team;
    if (tid == 0) j->used = nt;
    bvh__range(j->m, tid, nt, &lo, &hi);
    if (j->pass == 1)
        bvh__sm_pass1(j->s->work, j->b + (uint32_t)lo, j->b + (uint32_t)hi, j->x, j->slots, j->par->ts[tid].bin,
                      j->par->ts[tid].bin_n);
    else
        bvh__sm_pass2(j->s->c, j->s->work, j->b + (uint32_t)lo, j->b + (uint32_t)hi, j->x, j->clip, j->budget,
                      &j->par->sums[tid]);
}
static int bvh__sm_pass_team(bvh__sm *s, int pass, uint32_t b, uint32_t m, uint32_t budget, const bvh__sm_axis *x,
                             const uint32_t *slots, const int *clip, bvh__sm_sums *sums) {
    bvh__sm_par *par = s->par;
    bvh__sm_pass_job j;
    uint32_t t, k;
    int a;
    j.par = par;
    j.s = s;
    j.pass = pass;
    j.b = b;
    j.m = m;
    j.budget = budget;
    j.used = 0;
    j.x = x;
    j.slots = slots;
    j.clip = clip;
    if (bvh__run(s->c, par->nt, 0, bvh__sm_pass_fn, &j) != BVH_SUCCESS || !j.used) {
        par->oom = 1; /* the team's bookkeeping: the build fails once this node is decided */
        return 0;
    }
    if (pass == 1)
        for (a = 0; a < 3; a++)
            for (k = 0; k < slots[a]; k++) {
                s->bin[a][k] = par->ts[0].bin[a][k];
                s->bin_n[a][k] = par->ts[0].bin_n[a][k];
                for (t = 1; t < j.used; t++) {
                    s->bin[a][k] = bvh__merge(s->bin[a][k], par->ts[t].bin[a][k]);
                    s->bin_n[a][k] += par->ts[t].bin_n[a][k];
                }
            }
    else {
        *sums = par->sums[0];
        for (t = 1; t < j.used; t++) {
            const bvh__sm_sums *v = &par->sums[t];
            for (a = 0; a < 3; a++) {
                sums->dl[a] = bvh__merge(sums->dl[a], v->dl[a]);
                sums->dr[a] = bvh__merge(sums->dr[a], v->dr[a]);
                sums->sl[a] = bvh__merge(sums->sl[a], v->sl[a]);
                sums->sr[a] = bvh__merge(sums->sr[a], v->sr[a]);
                sums->ndl[a] += v->ndl[a];
                sums->ndr[a] += v->ndr[a];
                sums->nsl[a] += v->nsl[a];
                sums->nsr[a] += v->nsr[a];
                sums->dup[a] += v->dup[a];
                sums->over[a] |= v->over[a];
            }
        }
    }
    return 1;
}

/* Phase A: the nodes of at least par->threshold references, in the serial order. */
static bvh_result bvh__sm_phase_a(bvh__sm_par *par, bvh__sm_task root) {
    bvh__sm *s = par->s;
    const bvh__ctx *c = s->c;
    bvh__sm_task stack[BVH__SM_STACK];
    uint32_t sp = 1, gcarry = 0; /* gcarry: the guess's carry */
    stack[0] = root;
    while (sp) {
        bvh__sm_task t = stack[--sp], tl, tr;
        const uint32_t m = t.count, b = s->top - m;
        uint32_t left;
        bvh__sm_choice ch;
        bvh__sm_rec *rec;
        if (bvh__tick(c->prog, m, 0.0)) return BVH_ERROR_CANCELLED;
        if (!bvh__sm_grow(c, (void **)&par->rec, &par->rec_cap, par->nrec, sizeof *par->rec))
            return BVH_ERROR_OUT_OF_MEMORY;
        rec = &par->rec[par->nrec++];
        memset(rec, 0, sizeof *rec);
        rec->parent = t.parent;
        rec->right = t.right;
        rec->sub = BVH_INVALID;
        if (m < par->threshold) { /* a subtree for the threads */
            bvh__sm_sub *u;
            if (!bvh__sm_grow(c, (void **)&par->sub, &par->sub_cap, par->nsub, sizeof *par->sub))
                return BVH_ERROR_OUT_OF_MEMORY;
            rec->sub = par->nsub;
            u = &par->sub[par->nsub++];
            memset(u, 0, sizeof *u);
            u->t = t;
            u->t.node = 0;
            u->t.guess = t.guess + gcarry;
            gcarry = u->t.guess; /* as if it made no duplicates */
            u->in = par->in_used;
            memcpy(par->in + par->in_used, s->work + b, (size_t)m * sizeof *s->work);
            par->in_used += m;
            par->pending++;
            s->top = b;
            continue;
        }
        s->tight = 0;
        bvh__sm_decide(s, &t, &ch);
        if (par->oom) return BVH_ERROR_OUT_OF_MEMORY;
        BVH_ASSERT(ch.kind != BVH__SM_NONE); /* m > max_leaf */
        rec->dups = bvh__sm_children(s, &t, &ch, &tl, &tr);
        if (s->tight && par->pending && s->budget) return BVH__SM_FALLBACK; /* without splits budgets are 0 */
        rec->budget = t.budget;
        rec->nl = tl.count;
        rec->nr = tr.count;
        t.guess += gcarry;
        gcarry = 0;
        left = t.guess - rec->dups;
        tl.guess = (uint32_t)((uint64_t)left * tl.count / (tl.count + tr.count));
        tr.guess = left - tl.guess;
        rec->box = bvh__merge(tl.box, tr.box);
        tl.parent = tr.parent = par->nrec - 1;
        tl.right = 0;
        tr.right = 1;
        BVH_ASSERT(sp + 2 <= BVH__SM_STACK);
        stack[sp++] = tr;
        stack[sp++] = tl;
    }
    return BVH_SUCCESS;
}

/* Builds subtree u with `budget` from its references in par->in, with work room `work`, into
   nodes and refs (room for 2 (count + budget) - 1 and count + budget). */
static bvh_result bvh__sm_build_sub(bvh__sm_par *par, bvh__sm *st, bvh__sm_sub *u, uint32_t budget, uint32_t room,
                                    bvh__sm_ref *work, bvh_node *nodes, uint32_t *refs, uint32_t *cons) {
    bvh__out o;
    bvh__sm_task stack[BVH__SM_STACK];
    bvh_result r;
    const uint32_t m = u->t.count;
    memcpy(work, par->in + u->in, (size_t)m * sizeof *work);
    memset(&o, 0, sizeof o);
    o.nodes = nodes;
    o.refs = refs;
    o.node_count = 1;
    st->o = &o;
    st->work = work;
    st->top = m;
    st->budget = budget;
    st->room = room;
    st->cap = m + room;
    st->node_max = o.node_cap = 2 * st->cap - 1;
    o.ref_cap = st->cap;
    st->extra = st->carry = 0;
    st->tight = st->overflow = 0;
    st->cons = cons;
    stack[0] = u->t;
    stack[0].budget = budget;
    r = bvh__sm_run(st, stack, 1, NULL); /* the caller reports between rounds */
    BVH_ASSERT(r != BVH_SUCCESS || st->extra <= budget);
    u->built = budget;
    u->nodes = o.node_count;
    u->refs = o.ref_count;
    u->dups = st->extra;
    u->overflow = st->overflow;
    u->out_nodes = nodes;
    u->out_refs = refs;
    return r;
}

static size_t bvh__sm_take(bvh__sm_par *par, uint32_t tid, uint32_t nt, size_t *k) {
#if defined(__GNUC__) || defined(__clang__)
    (void)tid;
    (void)nt;
    (void)k;
    return __atomic_fetch_add(&par->next, (size_t)1, __ATOMIC_RELAXED);
#else
    size_t i = *k; /* no atomics: every nt-th subtree from tid on */
    *k += nt;
    return par->next + tid + i;
#endif
}
static void bvh__sm_sub_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    bvh__sm_par *par = BVH__CAST(bvh__sm_par *, arg);
    bvh__sm *st = &par->ts[tid];
    size_t k = 0, i;
    (void)team;
    while ((i = bvh__sm_take(par, tid, nt, &k)) < par->end)
        (void)bvh__sm_build_sub(par, st, &par->sub[par->order[i]], par->sub[par->order[i]].t.guess,
                                par->sub[par->order[i]].t.budget, par->scratch + (size_t)tid * par->scratch_cap,
                                par->arena_nodes + par->sub[par->order[i]].node_off,
                                par->arena_refs + par->sub[par->order[i]].ref_off,
                                par->cons + 4 * (size_t)par->sub[par->order[i]].node_off);
}

/* The subtrees' nodes and references into the tree, renumbered: children (local index >= 1)
   follow node_base, a leaf's references ref_base. */
static void bvh__sm_copy_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    bvh__sm_par *par = BVH__CAST(bvh__sm_par *, arg);
    bvh__out *o = par->out;
    size_t k = 0, i;
    uint32_t j;
    (void)team;
    while ((i = bvh__sm_take(par, tid, nt, &k)) < par->end) {
        const bvh__sm_sub *u = &par->sub[i];
        for (j = 0; j < u->nodes; j++) {
            bvh_node nd = u->out_nodes[j];
            nd.index += nd.count ? u->ref_base : u->node_base - 1;
            o->nodes[j ? u->node_base + j - 1 : u->g] = nd;
        }
        memcpy(o->refs + u->ref_base, u->out_refs, (size_t)u->refs * sizeof *o->refs);
    }
}

/* Whether subtree u, built with u->built, is the one the exact budget makes: the budgets flow
   through its nodes as in bvh__sm_run, each within the range its decisions hold for. */
static int bvh__sm_same(const bvh__sm_par *par, const bvh__sm_sub *u, uint32_t budget) {
    const uint32_t *cons = par->cons + 4 * (size_t)u->node_off;
    uint32_t stack[3 * BVH__SM_STACK], sp = 0, carry = 0;
    if (budget == u->built) return 1;
    stack[sp++] = 0; /* node, budget, references */
    stack[sp++] = budget;
    stack[sp++] = u->t.count;
    while (sp) {
        const uint32_t m = stack[--sp], j = stack[sp - 2], *k = cons + 4 * (size_t)j;
        uint32_t b = stack[sp - 1] + carry, left, first, nr;
        sp -= 2;
        carry = 0;
        if (b < k[0] || b > k[1]) return 0;
        if (u->out_nodes[j].count) { /* a leaf */
            carry = b;
            continue;
        }
        left = b - k[3];
        nr = m + k[3] - k[2];
        first = (uint32_t)((uint64_t)left * k[2] / (k[2] + nr));
        BVH_ASSERT(sp + 6 <= 3 * BVH__SM_STACK);
        stack[sp++] = u->out_nodes[j].index + 1;
        stack[sp++] = left - first;
        stack[sp++] = nr;
        stack[sp++] = u->out_nodes[j].index;
        stack[sp++] = first;
        stack[sp++] = k[2];
    }
    return 1;
}

/* The walk in the serial order: exact budgets (a subtree built with less and tight is built
   again), then the nodes and references numbered as the serial build numbers them. */
static bvh_result bvh__sm_assemble(bvh__sm_par *par, bvh__out *o) {
    bvh__sm *s = par->s;
    const bvh__ctx *c = s->c;
    uint32_t i, carry = 0, nodes = 1, refs = 0, next_node = 1, next_ref = 0;
    for (i = 0; i < par->nrec; i++) {
        bvh__sm_rec *x = &par->rec[i];
        uint32_t budget;
        if (x->parent == BVH_INVALID)
            budget = s->budget;
        else {
            const bvh__sm_rec *p = &par->rec[x->parent];
            uint32_t left = p->budget - p->dups, first = (uint32_t)((uint64_t)left * p->nl / (p->nl + p->nr));
            budget = x->right ? left - first : first;
        }
        budget += carry;
        carry = 0;
        if (x->sub == BVH_INVALID) {
            BVH_ASSERT(budget >= x->budget);
            x->budget = budget;
            nodes += 2;
            continue;
        }
        {
            bvh__sm_sub *u = &par->sub[x->sub];
            BVH_ASSERT(budget >= u->t.budget);
            if (u->overflow || !bvh__sm_same(par, u, budget)) { /* built again with its exact budget */
                const uint32_t cap = u->t.count + budget;
                bvh_node *bn = BVH__ALLOC(&c->al, bvh_node, 2 * (size_t)cap - 1);
                uint32_t *br = BVH__ALLOC(&c->al, uint32_t, cap);
                bvh_result r;
                if (!bn || !br) {
                    bvh__free(&c->al, bn);
                    bvh__free(&c->al, br);
                    return BVH_ERROR_OUT_OF_MEMORY;
                }
                u->own = 1;
                BVH__SM_EVENT(rebuilt);
                r = bvh__sm_build_sub(par, &par->ts[0], u, budget, budget, s->work, bn, br, NULL);
                if (r != BVH_SUCCESS) return r;
                if (bvh__report(c->prog, 0.0)) return BVH_ERROR_CANCELLED;
            }
            carry = budget - u->dups;
            nodes += u->nodes - 1;
            refs += u->refs;
        }
    }
    o->nodes = BVH__ALLOC(&c->al, bvh_node, nodes);
    o->refs = BVH__ALLOC(&c->al, uint32_t, refs);
    if (!o->nodes || !o->refs) return BVH_ERROR_OUT_OF_MEMORY;
    o->node_count = o->node_cap = nodes;
    o->ref_count = o->ref_cap = refs;
    for (i = 0; i < par->nrec; i++) {
        bvh__sm_rec *x = &par->rec[i];
        const uint32_t g = x->parent == BVH_INVALID ? 0 : par->rec[x->parent].base + x->right;
        if (x->sub == BVH_INVALID) {
            bvh_node *node = &o->nodes[g];
            x->base = next_node;
            next_node += 2;
            bvh__set_box(node, x->box);
            node->index = x->base;
            node->count = 0;
        } else {
            bvh__sm_sub *u = &par->sub[x->sub];
            u->g = g; /* copied by the threads (bvh__sm_copy_fn) */
            u->node_base = next_node;
            u->ref_base = next_ref;
            next_node += u->nodes - 1;
            next_ref += u->refs;
        }
    }
    BVH_ASSERT(next_node == nodes && next_ref == refs);
    par->out = o;
    par->next = 0;
    par->end = par->nsub;
    return bvh__run(c, par->nt, 0, bvh__sm_copy_fn, par);
}

static void bvh__sm_par_free(const bvh__ctx *c, bvh__sm_par *par) {
    uint32_t i;
    for (i = 0; i < par->nsub; i++)
        if (par->sub[i].own) {
            bvh__free(&c->al, par->sub[i].out_nodes);
            bvh__free(&c->al, par->sub[i].out_refs);
        }
    bvh__free(&c->al, par->ts);
    bvh__free(&c->al, par->sums);
    bvh__free(&c->al, par->in);
    bvh__free(&c->al, par->scratch);
    bvh__free(&c->al, par->rec);
    bvh__free(&c->al, par->sub);
    bvh__free(&c->al, par->order);
    bvh__free(&c->al, par->arena_nodes);
    bvh__free(&c->al, par->arena_refs);
    bvh__free(&c->al, par->cons);
}

/* Phase A, the subtrees on the threads, the assembly. BVH__SM_FALLBACK: build serially. */
static bvh_result bvh__sm_parallel(bvh__sm *s, bvh__sm_task root, uint32_t nt, bvh__out *o) {
    const bvh__ctx *c = s->c;
    bvh__sm_par par;
    bvh_result r;
    uint32_t i, j, nodes = 0, refs = 0;
    memset(&par, 0, sizeof par);
    par.s = s;
    par.nt = nt;
    /* every node of phase A is split (more references than a leaf may hold); about 8 subtrees
       per thread balance the threads */
    par.threshold = c->n / (8 * nt) > c->max_leaf ? c->n / (8 * nt) : c->max_leaf + 1;
    par.in = BVH__ALLOC(&c->al, bvh__sm_ref, s->cap);
    par.ts = BVH__ALLOC(&c->al, bvh__sm, nt);
    par.sums = BVH__ALLOC(&c->al, bvh__sm_sums, nt);
    s->par = &par;
    r = par.in && par.ts && par.sums ? bvh__sm_phase_a(&par, root) : BVH_ERROR_OUT_OF_MEMORY;
    s->par = NULL;
    if (r == BVH_SUCCESS) {
        /* the arena: each subtree's slot holds what its budget allows (2 (m + budget) - 1 nodes);
           the budgets are shares of the root's, so the slots fit in the serial build's bound */
        par.order = BVH__ALLOC(&c->al, uint32_t, par.nsub);
        for (i = 0; par.order && i < par.nsub; i++) {
            bvh__sm_sub *u = &par.sub[i];
            const uint32_t cap = u->t.count + u->t.budget;
            u->node_off = nodes;
            u->ref_off = refs;
            nodes += 2 * cap - 1;
            refs += cap;
            if (cap > par.scratch_cap) par.scratch_cap = cap;
            for (j = i; j > 0 && par.sub[par.order[j - 1]].t.count < u->t.count; j--) par.order[j] = par.order[j - 1];
            par.order[j] = i; /* largest first, ties in order */
        }
        par.arena_nodes = BVH__ALLOC(&c->al, bvh_node, nodes ? nodes : 1);
        par.cons = BVH__ALLOC(&c->al, uint32_t, 4 * (size_t)(nodes ? nodes : 1));
        par.arena_refs = BVH__ALLOC(&c->al, uint32_t, refs ? refs : 1);
        par.scratch = BVH__ALLOC(&c->al, bvh__sm_ref, (size_t)nt * par.scratch_cap);
        if (!par.order || !par.arena_nodes || !par.arena_refs || !par.scratch || !par.cons) r = BVH_ERROR_OUT_OF_MEMORY;
    }
    if (r == BVH_SUCCESS) {
        size_t lo, hi;
        for (i = 0; i < nt; i++) par.ts[i] = *s; /* s->par is NULL: the subtrees' passes are serial */
        /* in rounds of about BVH__PROGRESS_WORK / 2 references per thread at each level of a
           subtree (the serial loop ticks every BVH__PROGRESS_WORK), largest first, with a report after each on this
           thread: the same calls for any schedule, and a cancel between them */
        for (lo = 0; r == BVH_SUCCESS && lo < par.nsub; lo = hi) {
            uint64_t work = 0;
            for (hi = lo; hi < par.nsub && (hi - lo < nt || work < (uint64_t)nt * BVH__PROGRESS_WORK / 2); hi++) {
                const uint32_t m = par.sub[par.order[hi]].t.count;
                work += (uint64_t)m * (bvh__sm_log2(m) + 1);
            }
            par.next = lo;
            par.end = hi;
            r = bvh__run(c, nt, 0, bvh__sm_sub_fn, &par);
            if (r == BVH_SUCCESS && bvh__report(c->prog, (double)hi / par.nsub)) r = BVH_ERROR_CANCELLED;
        }
    }
    if (r == BVH_SUCCESS) r = bvh__sm_assemble(&par, o);
    bvh__sm_par_free(c, &par);
    return r;
}

/* The builder; bins = 0 is the study's variant (mid-point candidates only). */
static bvh_result bvh__sah_midpoint_build(const bvh__ctx *c, bvh__out *o, uint32_t bins) {
    bvh__sm *s;
    bvh__sm_task root, stack[BVH__SM_STACK];
    uint32_t i;
    bvh_result r = BVH_SUCCESS;
    double budget = c->split_budget > 0.0f ? floor((double)c->split_budget * (double)c->n) : 0.0;
    memset(o, 0, sizeof *o);
    s = BVH__ALLOC(&c->al, bvh__sm, 1);
    if (!s) return BVH_ERROR_OUT_OF_MEMORY;
    memset(s, 0, sizeof *s);
    s->c = c;
    s->o = o;
    s->bins = bins > BVH__SM_MAX_BINS ? BVH__SM_MAX_BINS : bins;
    s->budget = budget < (double)BVH__MAX_PRIMS ? (uint32_t)budget : BVH__MAX_PRIMS; /* n <= 2^30 */
    s->cap = c->n + s->budget;
    s->node_max = 2 * s->cap - 1;
    s->work = BVH__ALLOC(&c->al, bvh__sm_ref, s->cap);
    if (!s->work) {
        r = BVH_ERROR_OUT_OF_MEMORY;
        goto done;
    }
    for (i = 0; i < c->n; i++) {
        s->work[i].box = c->boxes[i];
        s->work[i].id = i;
    }
    s->top = c->n;
    memset(&root, 0, sizeof root);
    root.count = c->n;
    root.depth = 1;
    root.budget = root.guess = s->budget;
    root.parent = BVH_INVALID;
    s->room = 0xffffffffu;
    bvh__sm_bounds(s->work, c->n, &root.box, &root.cbox);
    s->root_area = bvh__half_area_d(root.box);
    if (c->threads > 1) {
        r = bvh__sm_parallel(s, root, c->threads, o);
        if (r != BVH__SM_FALLBACK) goto done;
        r = BVH_SUCCESS; /* start again, serially */
        BVH__SM_EVENT(serial);
        for (i = 0; i < c->n; i++) {
            s->work[i].box = c->boxes[i];
            s->work[i].id = i;
        }
        s->top = c->n;
        s->extra = s->carry = 0;
    }
    o->refs = BVH__ALLOC(&c->al, uint32_t, s->cap);
    o->node_cap = c->n < 1024 ? s->node_max : c->n; /* grown by half when full */
    o->nodes = BVH__ALLOC(&c->al, bvh_node, o->node_cap);
    o->ref_cap = s->cap;
    if (!o->refs || !o->nodes) {
        r = BVH_ERROR_OUT_OF_MEMORY;
        goto done;
    }
    o->node_count = 1;
    stack[0] = root;
    r = bvh__sm_run(s, stack, 1, c->prog);
done:
    BVH_ASSERT(s->extra <= s->budget);
    if (r != BVH_SUCCESS) bvh__out_free(c, o);
    bvh__free(&c->al, s->work);
    bvh__free(&c->al, s);
    return r;
}

static bvh_result bvh__build_sah_midpoint(const bvh__ctx *c, bvh__out *o) {
    return bvh__sah_midpoint_build(c, o, c->sah_bins);
}

/* ============================================================================================ */
/* == the builder table ========================================================================== */
/* One row per builder: everything bvh_build, the validator and bvh_builder_get_info need to know
   of it. A new builder is its section above plus one row here. */
/* ============================================================================================ */
typedef bvh_result (*bvh__build_fn)(bvh__ctx *c, bvh__out *o);
static bvh_result bvh__build_ploc_one(bvh__ctx *c, bvh__out *o) { return bvh__build_ploc(c, o, 1); }
static bvh_result bvh__build_ploc_team(bvh__ctx *c, bvh__out *o) { return bvh__build_ploc(c, o, c->threads); }
static bvh_result bvh__build_top_down_row(bvh__ctx *c, bvh__out *o) { return bvh__build_top_down(c, o); }
static bvh_result bvh__build_bottom_up_row(bvh__ctx *c, bvh__out *o) { return bvh__build_bottom_up(c, o); }
static bvh_result bvh__build_sah_midpoint_row(bvh__ctx *c, bvh__out *o) { return bvh__build_sah_midpoint(c, o); }
typedef struct bvh__builder_row {
    bvh_builder_info info;
    bvh__build_fn build;
} bvh__builder_row;
/* Row 0 (BVH_BUILDER_DEFAULT) stands for ploc-parallel: bvh__builder() resolves it. PLOC's
   collapse prices an interior node dearer (BVH__PLOC_INTERIOR): smaller trees, traced as fast.
   The defaults of the builder-specific options: radius, top, max_bytes_per_prim; bins,
   split_budget. */
#define BVH__PLOC_DEFAULTS                                                                                             \
    { 16, 8, 40 }
#define BVH__SAH_MIDPOINT_DEFAULTS                                                                                     \
    { 32, 0.3f }
#define BVH__NO_PLOC                                                                                                   \
    { 0, 0, 0 }
#define BVH__NO_SAH_MIDPOINT                                                                                           \
    { 0, 0.0f }
static const bvh__builder_row bvh__builders[BVH_BUILDER_COUNT] = {
    {{"default", 8, BVH__PLOC_INTERIOR, 1, 0, BVH__PLOC_DEFAULTS, BVH__NO_SAH_MIDPOINT}, bvh__build_ploc_team},
    {{"top-down", 4, 1.0f, 0, 0, BVH__NO_PLOC, BVH__NO_SAH_MIDPOINT}, bvh__build_top_down_row},
    {{"bottom-up", 4, 1.0f, 0, 0, BVH__NO_PLOC, BVH__NO_SAH_MIDPOINT}, bvh__build_bottom_up_row},
    {{"sah-midpoint", 8, 1.0f, 1, 1, BVH__NO_PLOC, BVH__SAH_MIDPOINT_DEFAULTS}, bvh__build_sah_midpoint_row},
    {{"ploc", 8, BVH__PLOC_INTERIOR, 0, 0, BVH__PLOC_DEFAULTS, BVH__NO_SAH_MIDPOINT}, bvh__build_ploc_one},
    {{"ploc-parallel", 8, BVH__PLOC_INTERIOR, 1, 0, BVH__PLOC_DEFAULTS, BVH__NO_SAH_MIDPOINT}, bvh__build_ploc_team},
};
static bvh_builder bvh__builder(bvh_builder b) { return b == BVH_BUILDER_DEFAULT ? BVH_BUILDER_PLOC_PARALLEL : b; }
BVH_API const char *bvh_builder_name(bvh_builder b) {
    return (unsigned)b < BVH_BUILDER_COUNT ? bvh__builders[b].info.name : "unknown";
}
BVH_API bvh_result bvh_builder_from_name(const char *name, bvh_builder *out) {
    int i;
    if (!name || !out) return BVH_ERROR_INVALID_ARGUMENT;
    for (i = 0; i < BVH_BUILDER_COUNT; i++)
        if (strcmp(name, bvh__builders[i].info.name) == 0) {
            *out = BVH__CAST(bvh_builder, i);
            return BVH_SUCCESS;
        }
    return BVH_ERROR_INVALID_ARGUMENT;
}
BVH_API bvh_result bvh_builder_get_info(bvh_builder b, bvh_builder_info *out) {
    if ((unsigned)b >= BVH_BUILDER_COUNT || !out) return BVH_ERROR_INVALID_ARGUMENT;
    *out = bvh__builders[bvh__builder(b)].info;
    return BVH_SUCCESS;
}

/* ============================================================================================ */
/* == build front-end ============================================================================ */
/* Checks the description, turns triangles (or caller boxes) into boxes and centroids, leaves out
   or refuses invalid primitives, runs the builder and maps its references back. */
/* ============================================================================================ */
static const float *bvh__vertex(const bvh_triangles *t, uint32_t v) {
    size_t stride = t->stride ? t->stride : 3 * sizeof(float);
    return BVH__CAST(
        const float *,
        BVH__CAST(const void *, BVH__CAST(const char *, BVH__CAST(const void *, t->positions)) + (size_t)v * stride));
}
/* memcpy: a stride that is no multiple of 4 (or an unaligned positions pointer) is read as well */
BVH__INLINE void bvh__fetch_triangle(const bvh_triangles *t, uint32_t i, float out[9]) {
    int k;
    for (k = 0; k < 3; k++) {
        uint32_t v = t->indices ? t->indices[3 * (size_t)i + k] : (uint32_t)(3 * (size_t)i + k);
        memcpy(out + 3 * k, bvh__vertex(t, v), 3 * sizeof(float));
    }
}
static int bvh__costs_valid(const bvh_costs *k) {
    return bvh__finite(k->interior) && bvh__finite(k->leaf) && bvh__finite(k->triangle) && k->interior >= 0.0f &&
           k->leaf >= 0.0f && k->triangle >= 0.0f;
}
/* BVH_OFF in the float option: the conversion is exact (2^31), so the comparison is too. */
static int bvh__split_budget_off(float b) { return b == (float)BVH_OFF; }
static bvh_result bvh__check_desc(const bvh_build_desc *d, uint32_t *count) {
    const bvh_triangles *t = &d->triangles;
    uint32_t i;
    if ((unsigned)d->builder >= BVH_BUILDER_COUNT) return BVH_ERROR_INVALID_ARGUMENT;
    if (d->max_leaf_size > BVH__MAX_LEAF || d->ploc.radius > 256) return BVH_ERROR_INVALID_ARGUMENT;
    if (d->trace_width != 0 && d->trace_width != 2 && d->trace_width != 8) return BVH_ERROR_INVALID_ARGUMENT;
    if (d->sah_midpoint.bins > 64 && d->sah_midpoint.bins != BVH_OFF) return BVH_ERROR_INVALID_ARGUMENT;
    if (!bvh__costs_valid(&d->costs)) return BVH_ERROR_INVALID_ARGUMENT;
    if (d->optimize.rounds > 1024 || !(d->optimize.batch <= 1.0f) || /* NaN too */
        (d->optimize.batch != 0.0f && !(d->optimize.batch >= 1.0f / 65536.0f)))
        return BVH_ERROR_INVALID_ARGUMENT;
    if (!bvh__split_budget_off(d->sah_midpoint.split_budget) &&
        !(d->sah_midpoint.split_budget >= 0.0f && d->sah_midpoint.split_budget <= 1.0f)) /* NaN too */
        return BVH_ERROR_INVALID_ARGUMENT;
    if (t->triangle_count && (d->boxes || d->box_count)) return BVH_ERROR_INVALID_ARGUMENT;
    if (d->box_count) {
        if (!d->boxes) return BVH_ERROR_INVALID_ARGUMENT;
        if (d->box_count > BVH__MAX_PRIMS) return BVH_ERROR_TOO_MANY_PRIMITIVES;
        *count = d->box_count;
        return BVH_SUCCESS;
    }
    *count = t->triangle_count;
    if (!t->triangle_count) return BVH_SUCCESS;
    if (!t->positions) return BVH_ERROR_INVALID_ARGUMENT;
    if (t->stride != 0 && t->stride < 3 * sizeof(float)) return BVH_ERROR_INVALID_ARGUMENT;
    if ((uintptr_t)t->indices % sizeof(uint32_t)) return BVH_ERROR_INVALID_ARGUMENT;
    if (t->triangle_count > BVH__MAX_PRIMS) return BVH_ERROR_TOO_MANY_PRIMITIVES;
    if (!t->indices) {
        if ((uint64_t)t->vertex_count < 3 * (uint64_t)t->triangle_count) return BVH_ERROR_INDEX_OUT_OF_RANGE;
    } else {
        for (i = 0; i < 3 * t->triangle_count; i++)
            if (t->indices[i] >= t->vertex_count) return BVH_ERROR_INDEX_OUT_OF_RANGE;
    }
    return BVH_SUCCESS;
}

BVH_API void bvh_free(bvh_tree *tree) {
    bvh_allocator al;
    if (!tree) return;
    al = tree->allocator;
    if (!tree->borrowed) {
        bvh__free(&al, tree->nodes);
        bvh__free(&al, tree->prims);
        bvh__free(&al, tree->tris);
    }
    bvh__free_lines(&al, tree->nodes8); /* tri4 lives in the same block */
    memset(tree, 0, sizeof *tree);
    tree->allocator = al;
}

/* Front end of bvh_build on the build's team: every primitive's box, the bounds of the boxes and
   of their centroids per thread, and the invalid primitives (NaN/Inf, or a box with min > max),
   whose box is marked with a NaN for bvh_build to refuse or leave out. */
typedef struct bvh__front_part {
    bvh_aabb bounds, cbounds;
    uint32_t invalid;
} bvh__front_part;
typedef struct bvh__front {
    const bvh_build_desc *desc;
    bvh_aabb *boxes;
    bvh__front_part *part;
    uint32_t count, nt;
} bvh__front;
static void bvh__front_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    bvh__front *f = BVH__CAST(bvh__front *, arg);
    const bvh_build_desc *d = f->desc;
    bvh__front_part *part = &f->part[tid];
    bvh_aabb bounds = bvh__empty(), cbounds = bvh__empty();
    uint32_t invalid = 0;
    size_t b, e, i;
    (void)team;
    if (tid == 0) f->nt = nt; /* the team may be smaller than asked for */
    bvh__range(f->count, tid, nt, &b, &e);
    for (i = b; i < e; i++) {
        bvh_aabb box;
        int ok;
        if (d->boxes) {
            box = d->boxes[i];
            ok = bvh__finite3(&box.min.x) && bvh__finite3(&box.max.x) && box.min.x <= box.max.x &&
                 box.min.y <= box.max.y && box.min.z <= box.max.z;
        } else {
            float t[9];
            bvh__fetch_triangle(&d->triangles, (uint32_t)i, t);
            ok = bvh__finite3(t) && bvh__finite3(t + 3) && bvh__finite3(t + 6);
            box = bvh__tri_box(t);
        }
        if (!ok) {
            box.min.x = NAN;
            invalid++;
        } else {
            bounds = bvh__merge(bounds, box);
            bvh__grow(&cbounds, bvh__centroid(box));
        }
        f->boxes[i] = box;
    }
    part->bounds = bounds;
    part->cbounds = cbounds;
    part->invalid = invalid;
}
/* Back end: the tree's triangles in reference order, references mapped to the caller's ids. */
typedef struct bvh__back {
    const bvh__ctx *c;
    bvh_tree *tree;
} bvh__back;
static void bvh__back_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    const bvh__back *k = BVH__CAST(const bvh__back *, arg);
    const bvh__ctx *c = k->c;
    bvh_tree *tree = k->tree;
    size_t b, e, i;
    (void)team;
    bvh__range(tree->ref_count, tid, nt, &b, &e);
    for (i = b; i < e; i++) {
        uint32_t local = tree->prims[i];
        if (c->tris) {
            /* the references are in tree order, the triangles in the caller's: ask ahead for the
               indices of the 16th triangle on and for the vertices of the 8th */
            const bvh_triangles *t = c->tris;
            if (i + 16 < e) {
                uint32_t id = tree->prims[i + 16];
                id = c->orig ? c->orig[id] : id;
                if (t->indices)
                    BVH__PREFETCH(&t->indices[3 * (size_t)id]);
                else
                    BVH__PREFETCH(bvh__vertex(t, 3 * id));
            }
            if (t->indices && i + 8 < e) {
                uint32_t id = tree->prims[i + 8];
                const uint32_t *ix = &t->indices[3 * (size_t)(c->orig ? c->orig[id] : id)];
                BVH__PREFETCH(bvh__vertex(t, ix[0]));
                BVH__PREFETCH(bvh__vertex(t, ix[1]));
                BVH__PREFETCH(bvh__vertex(t, ix[2]));
            }
            bvh__ctx_triangle(c, local, tree->tris + 9 * i);
        }
        if (c->orig) tree->prims[i] = c->orig[local];
    }
}

/* The one place where the zero-means-default description becomes the builder's options (the
   description is checked first, by bvh__check_desc): 0 takes the default of the builder's row,
   BVH_OFF turns an option off. */
static void bvh__resolve(const bvh_build_desc *d, bvh_builder builder, uint32_t count, bvh__ctx *c) {
    const bvh_builder_info *row = &bvh__builders[builder].info;
    memset(c, 0, sizeof *c);
    c->al = d->allocator;
    c->pool = d->pool.run ? &d->pool : NULL;
    c->max_leaf = d->max_leaf_size ? d->max_leaf_size : row->max_leaf_size;
    c->threads = row->uses_threads ? bvh__resolve_threads(d->threads) : 1;
    /* a thread per BVH__MIN_PRIMS_PER_THREAD primitives at most: on small inputs, creating threads
       and meeting at barriers costs more than the work (the tree does not depend on the count) */
    if (c->threads > 1 && count / BVH__MIN_PRIMS_PER_THREAD < c->threads)
        c->threads = count / BVH__MIN_PRIMS_PER_THREAD > 1 ? count / BVH__MIN_PRIMS_PER_THREAD : 1;
    c->radius = d->ploc.radius ? d->ploc.radius : row->ploc.radius;
    c->ploc_top = d->ploc.top ? d->ploc.top : row->ploc.top;
    c->ploc_top = c->ploc_top == BVH_OFF ? 0 : c->ploc_top < 2 ? 2 : c->ploc_top;
    c->sah_bins = d->sah_midpoint.bins ? d->sah_midpoint.bins : row->sah_midpoint.bins;
    if (c->sah_bins == BVH_OFF) c->sah_bins = 0;
    if (d->costs.interior == 0.0f && d->costs.leaf == 0.0f && d->costs.triangle == 0.0f) {
        c->ci = row->interior_cost;
        c->cl = 0.0f;
        c->ct = 1.0f;
    } else {
        c->ci = d->costs.interior;
        c->cl = d->costs.leaf;
        c->ct = d->costs.triangle;
    }
    c->budget = d->ploc.max_bytes_per_prim ? d->ploc.max_bytes_per_prim : row->ploc.max_bytes_per_prim;
    if (c->budget == BVH_OFF) c->budget = 0;
    c->split_budget =
        d->sah_midpoint.split_budget == 0.0f ? row->sah_midpoint.split_budget : d->sah_midpoint.split_budget;
    if (bvh__split_budget_off(c->split_budget)) c->split_budget = 0.0f;
    c->opt_rounds = d->optimize.rounds;
    c->opt_batch = d->optimize.batch == 0.0f ? BVH__OPT_BATCH : d->optimize.batch;
    c->opt_threads = bvh__resolve_threads(d->threads); /* every builder's optimizer runs on them */
    if (c->opt_threads > 1 && count / BVH__MIN_PRIMS_PER_THREAD < c->opt_threads)
        c->opt_threads = count / BVH__MIN_PRIMS_PER_THREAD > 1 ? count / BVH__MIN_PRIMS_PER_THREAD : 1;
}

static bvh_result bvh__make_wide(bvh_tree *tree, const bvh_allocator *al, const bvh_thread_pool *pool,
                                 uint32_t threads);
BVH_API bvh_result bvh_build(bvh_tree *tree, const bvh_build_desc *desc) {
    bvh__ctx c;
    bvh__out o;
    bvh__progress prog;
    uint32_t count = 0, i, n = 0, *orig = NULL;
    bvh_result r;
    bvh_builder builder;
    if (!tree) return BVH_ERROR_INVALID_ARGUMENT;
    memset(tree, 0, sizeof *tree);
    if (!desc) return BVH_ERROR_INVALID_ARGUMENT;
    tree->allocator = desc->allocator;
    r = bvh__check_desc(desc, &count);
    if (r == BVH_SUCCESS) r = bvh__allocator_ok(&desc->allocator);
    if (r != BVH_SUCCESS) return r;
    builder = bvh__builder(desc->builder);
    tree->builder = builder;
    tree->prim_count = count;
    memset(&o, 0, sizeof o);
    bvh__resolve(desc, builder, count, &c);
    memset(&prog, 0, sizeof prog);
    prog.fn = desc->progress;
    prog.user = desc->progress_user;
    c.prog = &prog;
    bvh__stage(&prog, 0.0f, BVH__STAGE_BUILD_LO);
    if (bvh__report(&prog, 0.0)) {
        r = BVH_ERROR_CANCELLED;
        goto fail;
    }
    if (count == 0) goto empty; /* an empty tree: node_count 0, every ray misses */

    c.boxes = BVH__ALLOC(&c.al, bvh_aabb, count);
    if (!c.boxes) {
        r = BVH_ERROR_OUT_OF_MEMORY;
        goto fail;
    }
    {
        /* boxes, bounds and validity on the build's threads (one for every builder but
           ploc-parallel); bounds are min/max, so the result does not depend on the split */
        bvh__front fr;
        memset(&fr, 0, sizeof fr);
        fr.desc = desc;
        fr.boxes = c.boxes;
        fr.count = count;
        fr.nt = c.threads;
        fr.part = BVH__ALLOC(&c.al, bvh__front_part, c.threads);
        if (!fr.part) {
            r = BVH_ERROR_OUT_OF_MEMORY;
            goto fail;
        }
        r = bvh__run(&c, c.threads, 0, bvh__front_fn, &fr);
        c.bounds = c.cbounds = bvh__empty();
        for (i = 0; r == BVH_SUCCESS && i < fr.nt; i++) {
            c.bounds = bvh__merge(c.bounds, fr.part[i].bounds);
            c.cbounds = bvh__merge(c.cbounds, fr.part[i].cbounds);
            n += fr.part[i].invalid;
        }
        bvh__free(&c.al, fr.part);
        if (r == BVH_SUCCESS && bvh__report(&prog, 1.0)) r = BVH_ERROR_CANCELLED;
        if (r != BVH_SUCCESS) goto fail;
    }
    if (n > 0) { /* some primitives are invalid (marked by a NaN box): refuse, or leave them out */
        if (!desc->skip_invalid) {
            r = BVH_ERROR_INVALID_GEOMETRY;
            goto fail;
        }
        if (!(orig = BVH__ALLOC(&c.al, uint32_t, count))) {
            r = BVH_ERROR_OUT_OF_MEMORY;
            goto fail;
        }
        c.bounds = c.cbounds = bvh__empty();
        for (i = 0, n = 0; i < count; i++) {
            bvh_aabb box = c.boxes[i];
            if (bvh__nan(box.min.x)) continue;
            orig[n] = i;
            c.boxes[n++] = box;
            c.bounds = bvh__merge(c.bounds, box);
            bvh__grow(&c.cbounds, bvh__centroid(box));
        }
    } else {
        n = count;
    }
    tree->excluded = count - n;
    c.n = n;
    c.tris = desc->boxes ? NULL : &desc->triangles;
    c.in_boxes = desc->boxes;
    c.orig = orig;
    if (n == 0) goto empty;

    bvh__stage(&prog, BVH__STAGE_BUILD_LO, BVH__STAGE_BUILD_HI);
    if ((r = bvh__builders[builder].build(&c, &o)) != BVH_SUCCESS) goto fail;
    bvh__stage(&prog, BVH__STAGE_BUILD_HI, BVH__STAGE_WIDE_LO);
    if (c.opt_rounds && !c.opt_done) { /* builders without their own collapse: the optimizer here */
        bvh__out opt;
        r = bvh__optimize_emit(&c, o.nodes, 0, o.node_count, o.refs, !bvh__builders[builder].info.splits_references,
                               c.opt_threads, &opt);
        bvh__out_free(&c, &o);
        if (r != BVH_SUCCESS) goto fail;
        o = opt;
    }
    if (bvh__report(&prog, 0.0)) {
        r = BVH_ERROR_CANCELLED;
        goto fail;
    }
    bvh__free(&c.al, c.boxes);
    c.boxes = NULL;

    /* exact-size outputs: nodes, references mapped to caller indices, triangles in reference order */
    if (c.tris && !(tree->tris = BVH__ALLOC(&c.al, float, 9 * (size_t)o.ref_count))) {
        r = BVH_ERROR_OUT_OF_MEMORY;
        goto fail;
    }
    if (o.node_count == o.node_cap) {
        tree->nodes = o.nodes;
        o.nodes = NULL;
    } /* exact size: adopt */
    else if ((tree->nodes = BVH__ALLOC(&c.al, bvh_node, o.node_count)) != NULL)
        memcpy(tree->nodes, o.nodes, (size_t)o.node_count * sizeof(bvh_node));
    else {
        r = BVH_ERROR_OUT_OF_MEMORY;
        goto fail;
    }
    if (o.ref_count == o.ref_cap) {
        tree->prims = o.refs;
        o.refs = NULL;
    } else if ((tree->prims = BVH__ALLOC(&c.al, uint32_t, o.ref_count)) != NULL)
        memcpy(tree->prims, o.refs, (size_t)o.ref_count * sizeof(uint32_t));
    else {
        r = BVH_ERROR_OUT_OF_MEMORY;
        goto fail;
    }
    tree->node_count = o.node_count;
    tree->ref_count = o.ref_count;
    if (c.tris || orig) { /* triangles in reference order, references to caller ids */
        bvh__back bk;
        bk.c = &c;
        bk.tree = tree;
        r = bvh__run(&c, c.threads, 0, bvh__back_fn, &bk);
        if (r != BVH_SUCCESS) goto fail;
    }
    bvh__stage(&prog, BVH__STAGE_WIDE_LO, 1.0f);
    if (bvh__report(&prog, 0.0)) {
        r = BVH_ERROR_CANCELLED;
        goto fail;
    }
    bvh__out_free(&c, &o); /* first, so that the 8-wide copy does not add to the peak */
    bvh__free(&c.al, orig);
    orig = NULL;
    if (c.tris && desc->trace_width != 2 && (r = bvh__make_wide(tree, &c.al, c.pool, c.threads)) != BVH_SUCCESS)
        goto fail;
empty:
    /* complete: 1 is reported once, and its answer no longer cancels */
    bvh__stage(&prog, 1.0f, 1.0f);
    (void)bvh__report(&prog, 1.0);
    bvh__out_free(&c, &o);
    bvh__free(&c.al, orig);
    bvh__free(&c.al, c.boxes);
    return BVH_SUCCESS;
fail:
    bvh__out_free(&c, &o);
    bvh__free(&c.al, orig);
    bvh__free(&c.al, c.boxes);
    bvh_free(tree);
    tree->builder = BVH_BUILDER_DEFAULT;
    return r;
}

/* ============================================================================================ */
/* == SAH, statistics, validation ================================================================ */
/* ============================================================================================ */
BVH_API bvh_aabb bvh_tree_bounds(const bvh_tree *tree) {
    if (!tree || !tree->node_count) return bvh_aabb_empty();
    return bvh__node_box(&tree->nodes[0]);
}

/* Visits every node reached from the root, parents before children, with its depth (root 1).
   Trusts nothing: BVH_ERROR_INVALID_TREE for a child index out of range, a tree deeper than
   BVH_MAX_DEPTH (so a cycle ends) or a node count that differs from the nodes reached. */
typedef void (*bvh__visit_fn)(void *ctx, const bvh_node *n, uint32_t depth);
static bvh_result bvh__walk(const bvh_tree *tree, bvh__visit_fn visit, void *ctx) {
    uint32_t stack[2 * BVH_MAX_DEPTH + 2], sp = 0, reached = 0;
    if (!tree->node_count) return BVH_SUCCESS;
    if (!tree->nodes) return BVH_ERROR_INVALID_TREE;
    stack[sp++] = 0;
    stack[sp++] = 1;
    while (sp) {
        uint32_t depth = stack[--sp], ni = stack[--sp];
        const bvh_node *n = &tree->nodes[ni];
        visit(ctx, n, depth);
        reached++;
        if (n->count) continue;
        if (depth > BVH_MAX_DEPTH || n->index == 0 || n->index + 1 >= tree->node_count ||
            sp + 4 > 2 * BVH_MAX_DEPTH + 2)
            return BVH_ERROR_INVALID_TREE;
        stack[sp++] = n->index;
        stack[sp++] = depth + 1;
        stack[sp++] = n->index + 1;
        stack[sp++] = depth + 1;
    }
    return reached == tree->node_count ? BVH_SUCCESS : BVH_ERROR_INVALID_TREE;
}

typedef struct bvh__sah_sum {
    double root, si, sl, st;
} bvh__sah_sum;
static void bvh__sah_visit(void *ctx, const bvh_node *n, uint32_t depth) {
    bvh__sah_sum *s = BVH__CAST(bvh__sah_sum *, ctx);
    double a = s->root > 0.0 ? bvh__half_area_d(bvh__node_box(n)) / s->root : 1.0;
    (void)depth;
    if (n->count) {
        s->sl += a;
        s->st += a * n->count;
    } else {
        s->si += a;
    }
}
BVH_API bvh_result bvh_sah(const bvh_tree *tree, const bvh_costs *costs, double *out) {
    double ci = 1.0, cl = 0.0, ct = 1.0;
    bvh__sah_sum sum;
    bvh_result r;
    if (!tree || !out) return BVH_ERROR_INVALID_ARGUMENT;
    if (costs && !bvh__costs_valid(costs)) return BVH_ERROR_INVALID_ARGUMENT;
    if (costs && (costs->interior != 0.0f || costs->leaf != 0.0f || costs->triangle != 0.0f)) {
        ci = costs->interior;
        cl = costs->leaf;
        ct = costs->triangle;
    }
    *out = 0.0;
    if (!tree->node_count) return BVH_SUCCESS;
    if (!tree->nodes) return BVH_ERROR_INVALID_TREE;
    memset(&sum, 0, sizeof sum);
    sum.root = bvh__half_area_d(bvh__node_box(&tree->nodes[0]));
    if ((r = bvh__walk(tree, bvh__sah_visit, &sum)) != BVH_SUCCESS) return r;
    *out = ci * sum.si + cl * sum.sl + ct * sum.st;
    return BVH_SUCCESS;
}

static void bvh__stats_visit(void *ctx, const bvh_node *n, uint32_t depth) {
    bvh_stats *s = BVH__CAST(bvh_stats *, ctx);
    if (depth > s->max_depth) s->max_depth = depth;
    if (!n->count) return;
    s->leaves++;
    if (n->count > s->max_leaf_size) s->max_leaf_size = n->count;
}
BVH_API bvh_result bvh_get_stats(const bvh_tree *tree, bvh_stats *s) {
    if (!tree || !s) return BVH_ERROR_INVALID_ARGUMENT;
    memset(s, 0, sizeof *s);
    s->nodes = tree->node_count;
    s->refs = tree->ref_count;
    s->bytes = (size_t)tree->node_count * sizeof(bvh_node) + (size_t)tree->ref_count * sizeof(uint32_t);
    s->triangle_bytes = tree->tris ? (size_t)tree->ref_count * 9 * sizeof(float) : 0;
    s->wide_bytes = (size_t)tree->node8_count * sizeof(bvh_node8) + (size_t)tree->tri4_count * sizeof(bvh_tri4);
    return bvh__walk(tree, bvh__stats_visit, s);
}

static bvh_result bvh__invalid(bvh_validation *rep, uint32_t node, const char *msg) {
    if (rep) {
        size_t l = strlen(msg);
        if (l >= sizeof rep->message) l = sizeof rep->message - 1;
        memcpy(rep->message, msg, l);
        rep->message[l] = 0;
        rep->node = node;
    }
    return BVH_ERROR_INVALID_TREE;
}

/* Lane i of packet p as nine floats. */
static void bvh__lane(const bvh_tri4 *p, int i, float tri[9]) {
    int v, a;
    for (v = 0; v < 3; v++)
        for (a = 0; a < 3; a++) tri[3 * v + a] = p->v[v][a][i];
}
/* A lane whose three vertices coincide: how packets hold a zero-area triangle (no ray hits it,
   so where it lies cannot matter; a split reference's clipped box need not hold the point). */
static int bvh__lane_is_point(const float *tri) {
    return tri[0] == tri[3] && tri[0] == tri[6] && tri[1] == tri[4] && tri[1] == tri[7] && tri[2] == tri[5] &&
           tri[2] == tri[8];
}
/* An 8-wide leaf slot: its packets inside the packet array, each reached once (*cover), every lane
   a primitive of the tree inside (with split references: touching) the slot's box; seen[prim]
   counts the packets that hold prim. */
static const char *bvh__validate_packets(const bvh_tree *tree, const bvh_aabb *prim_boxes, int splits, bvh_aabb box,
                                         uint32_t first, uint32_t count, uint8_t *cover, uint32_t *seen) {
    uint32_t k;
    int i, j;
    if (first > tree->tri4_count || count > tree->tri4_count - first) return "8-wide leaf outside the packet array";
    for (k = first; k < first + count; k++) {
        const bvh_tri4 *p = &tree->tri4[k];
        if (cover[k]++) return "packet in two 8-wide leaves";
        for (i = 0; i < 4; i++) { /* the packet's lanes */
            float tri[9];
            bvh_aabb pb;
            if (p->prim[i] >= tree->prim_count) return "packet lane with a primitive out of range";
            for (j = 0; j < i && p->prim[j] != p->prim[i]; j++) {
            }
            if (j < i) continue; /* a repeated lane */
            bvh__lane(p, i, tri);
            pb = prim_boxes ? prim_boxes[p->prim[i]] : bvh__tri_box(tri);
            if (bvh__lane_is_point(tri)) { /* a zero-area triangle's stand-in, never hit */
                seen[p->prim[i]]++;
                continue;
            }
            if (splits ? !(pb.min.x <= box.max.x && pb.min.y <= box.max.y && pb.min.z <= box.max.z &&
                           pb.max.x >= box.min.x && pb.max.y >= box.min.y && pb.max.z >= box.min.z)
                       : !bvh_aabb_contains(box, bvh__tri_box(tri)))
                return "8-wide leaf box does not hold its primitive";
            seen[p->prim[i]]++;
        }
    }
    return NULL;
}
/* The 8-wide layout: every slot empty (+inf/-inf box, no child) or a valid box inside its parent's
   slot; interior slots point forward in the array (no cycles); every packet is in one leaf, and
   every referenced primitive in a packet (exactly one unless the builder splits references). */
static bvh_result bvh__validate_wide(const bvh_tree *tree, const bvh_aabb *prim_boxes, int splits,
                                     bvh_validation *rep) {
    bvh_allocator al = tree->allocator;
    uint32_t stack[BVH__W * (BVH_MAX_DEPTH + 2)][2], sp = 0, reached = 0, i, k, *seen;
    uint8_t *cover;
    bvh_aabb root = bvh__node_box(&tree->nodes[0]); /* deeper slots are checked against their parent's */
    bvh_result r = BVH_SUCCESS;
    if (!tree->node8_count || !tree->tri4)
        return bvh__invalid(rep, BVH_INVALID, "8-wide node array without nodes or packets");
    cover = BVH__ALLOC(&al, uint8_t, tree->tri4_count ? tree->tri4_count : 1);
    seen = BVH__ALLOC(&al, uint32_t, tree->prim_count ? tree->prim_count : 1);
    if (!cover || !seen) {
        r = BVH_ERROR_OUT_OF_MEMORY;
        goto done;
    }
    memset(cover, 0, tree->tri4_count ? tree->tri4_count : 1);
    memset(seen, 0, (tree->prim_count ? tree->prim_count : 1) * sizeof(uint32_t));
    stack[sp][0] = 0;
    stack[sp][1] = 0;
    sp++;
    while (sp) {
        uint32_t w = stack[--sp][0], depth = stack[sp][1];
        const bvh_node8 *n = &tree->nodes8[w];
        reached++;
        if (depth > BVH_MAX_DEPTH) {
            r = bvh__invalid(rep, w, "8-wide tree deeper than BVH_MAX_DEPTH");
            goto done;
        }
        for (i = 0; i < BVH__W; i++) {
            bvh_aabb box;
            box.min.x = n->min[0][i];
            box.min.y = n->min[1][i];
            box.min.z = n->min[2][i];
            box.max.x = n->max[0][i];
            box.max.y = n->max[1][i];
            box.max.z = n->max[2][i];
            if (!n->count[i] && box.min.x == BVH_INF && box.min.y == BVH_INF && box.min.z == BVH_INF &&
                box.max.x == -BVH_INF && box.max.y == -BVH_INF && box.max.z == -BVH_INF) {
                if (n->child[i]) {
                    r = bvh__invalid(rep, w, "empty 8-wide slot with a child");
                    goto done;
                }
                continue;
            }
            if (!(box.min.x <= box.max.x && box.min.y <= box.max.y && box.min.z <= box.max.z)) {
                r = bvh__invalid(rep, w, "8-wide slot box empty or NaN");
                goto done;
            }
            if (!bvh_aabb_contains(root, box)) {
                r = bvh__invalid(rep, w, "8-wide slot box not inside the root");
                goto done;
            }
            if (n->count[i]) {
                const char *msg =
                    bvh__validate_packets(tree, prim_boxes, splits, box, n->child[i], n->count[i], cover, seen);
                if (msg) {
                    r = bvh__invalid(rep, w, msg);
                    goto done;
                }
            } else {
                const bvh_node8 *c;
                uint32_t j;
                if (n->child[i] <= w || n->child[i] >= tree->node8_count) {
                    r = bvh__invalid(rep, w, "8-wide child index out of range");
                    goto done;
                }
                c = &tree->nodes8[n->child[i]];
                for (j = 0; j < BVH__W; j++) /* the child's slots inside this slot (empty ones trivially) */
                    if (!(c->min[0][j] >= box.min.x && c->min[1][j] >= box.min.y && c->min[2][j] >= box.min.z &&
                          c->max[0][j] <= box.max.x && c->max[1][j] <= box.max.y && c->max[2][j] <= box.max.z) &&
                        !(c->min[0][j] == BVH_INF && c->max[0][j] == -BVH_INF)) {
                        r = bvh__invalid(rep, n->child[i], "8-wide slot box not inside its parent");
                        goto done;
                    }
                if (sp == BVH__W * (BVH_MAX_DEPTH + 2)) {
                    r = bvh__invalid(rep, w, "8-wide tree deeper than BVH_MAX_DEPTH");
                    goto done;
                }
                stack[sp][0] = n->child[i];
                stack[sp][1] = depth + 1;
                sp++;
            }
        }
    }
    if (reached != tree->node8_count) {
        r = bvh__invalid(rep, BVH_INVALID, "8-wide nodes not reached exactly once from the root");
        goto done;
    }
    for (k = 0; k < tree->tri4_count; k++)
        if (!cover[k]) {
            r = bvh__invalid(rep, BVH_INVALID, "packet in no 8-wide leaf");
            goto done;
        }
    for (k = 0; k < tree->ref_count; k++) {
        uint32_t p = tree->prims[k];
        if (!seen[p] || (!splits && seen[p] != 1)) {
            r = bvh__invalid(rep, BVH_INVALID, "primitive not in exactly one 8-wide leaf packet");
            goto done;
        }
    }
done:
    bvh__free(&al, cover);
    bvh__free(&al, seen);
    return r;
}

/* bvh_validate; structure_only: without prim_boxes or triangles, the leaves' boxes are not checked
   against their primitives (bvh_load's check of a box tree, whose boxes it does not have). */
static bvh_result bvh__validate(const bvh_tree *tree, const bvh_aabb *prim_boxes, int structure_only,
                                bvh_validation *rep) {
    bvh_allocator al;
    uint8_t *seen = NULL, *used = NULL, *covered = NULL; /* covered: per reference, by a leaf */
    uint32_t stack[2 * BVH_MAX_DEPTH + 8], sp = 0, i, refs_seen = 0;
    int splits;
    bvh_result r = BVH_SUCCESS;
    if (rep) {
        rep->node = BVH_INVALID;
        strcpy(rep->message, "ok");
    }
    if (!tree || !bvh__allocator_paired(&tree->allocator)) return BVH_ERROR_INVALID_ARGUMENT;
    al = tree->allocator;
    if (!tree->node_count) {
        if (tree->ref_count) return bvh__invalid(rep, BVH_INVALID, "empty tree with references");
        if (tree->prim_count != tree->excluded)
            return bvh__invalid(rep, BVH_INVALID, "primitives missing from an empty tree");
        return BVH_SUCCESS;
    }
    if (!tree->nodes || !tree->prims) return bvh__invalid(rep, BVH_INVALID, "node or reference array missing");
    if (!prim_boxes && !tree->tris && !structure_only) {
        bvh__invalid(rep, BVH_INVALID, "a tree built from boxes is checked against those boxes: prim_boxes is NULL");
        return BVH_ERROR_INVALID_ARGUMENT;
    }
    splits = tree->ref_count != tree->prim_count - tree->excluded;
    if ((unsigned)tree->builder >= BVH_BUILDER_COUNT) return bvh__invalid(rep, BVH_INVALID, "builder out of range");
    if (splits && !bvh__builders[tree->builder].info.splits_references)
        return bvh__invalid(rep, BVH_INVALID,
                            "reference count differs from primitive count for a builder that does not split");
    seen = BVH__ALLOC(&al, uint8_t, tree->node_count);
    used = BVH__ALLOC(&al, uint8_t, tree->prim_count ? tree->prim_count : 1);
    covered = BVH__ALLOC(&al, uint8_t, tree->ref_count ? tree->ref_count : 1);
    if (!seen || !used || !covered) {
        r = BVH_ERROR_OUT_OF_MEMORY;
        goto done;
    }
    memset(seen, 0, tree->node_count);
    memset(used, 0, tree->prim_count ? tree->prim_count : 1);
    memset(covered, 0, tree->ref_count ? tree->ref_count : 1);
    stack[sp++] = 0;
    stack[sp++] = 1;
    while (sp) {
        uint32_t depth = stack[--sp], ni = stack[--sp];
        const bvh_node *n = &tree->nodes[ni];
        bvh_aabb box = bvh__node_box(n);
        if (seen[ni]++) {
            r = bvh__invalid(rep, ni, "node reached twice");
            goto done;
        }
        if (depth > BVH_MAX_DEPTH) {
            r = bvh__invalid(rep, ni, "tree deeper than BVH_MAX_DEPTH");
            goto done;
        }
        if (!(box.min.x <= box.max.x && box.min.y <= box.max.y && box.min.z <= box.max.z)) {
            r = bvh__invalid(rep, ni, "node box empty or NaN");
            goto done;
        }
        if (n->count) {
            uint32_t k;
            if (n->index > tree->ref_count || n->count > tree->ref_count - n->index) {
                r = bvh__invalid(rep, ni, "leaf range outside the reference array");
                goto done;
            }
            for (k = n->index; k < n->index + n->count; k++) {
                uint32_t p = tree->prims[k];
                bvh_aabb pb;
                refs_seen++;
                if (covered[k]++) { /* with the count below: every reference in exactly one leaf */
                    r = bvh__invalid(rep, ni, "reference in two leaves");
                    goto done;
                }
                if (p >= tree->prim_count) {
                    r = bvh__invalid(rep, ni, "reference to a primitive out of range");
                    goto done;
                }
                if (used[p] && !splits) {
                    r = bvh__invalid(rep, ni, "primitive referenced twice");
                    goto done;
                }
                used[p] = 1;
                if (!prim_boxes && !tree->tris) continue; /* structure_only */
                pb = prim_boxes ? prim_boxes[p] : bvh__tri_box(tree->tris + 9 * (size_t)k);
                if (splits ? !(pb.min.x <= box.max.x && pb.min.y <= box.max.y && pb.min.z <= box.max.z &&
                               pb.max.x >= box.min.x && pb.max.y >= box.min.y && pb.max.z >= box.min.z)
                           : !bvh_aabb_contains(box, pb)) {
                    r = bvh__invalid(rep, ni,
                                     splits ? "leaf box does not touch its primitive"
                                            : "leaf box does not contain its primitive");
                    goto done;
                }
            }
            continue;
        }
        if (n->index == 0 || n->index >= tree->node_count - 1) {
            r = bvh__invalid(rep, ni, "child index out of range");
            goto done;
        }
        if (n->index <= ni) {
            r = bvh__invalid(rep, ni, "child stored before its parent");
            goto done;
        }
        for (i = 0; i < 2; i++) {
            if (!bvh_aabb_contains(box, bvh__node_box(&tree->nodes[n->index + i]))) {
                r = bvh__invalid(rep, n->index + i, "child box not inside its parent");
                goto done;
            }
            stack[sp++] = n->index + i;
            stack[sp++] = depth + 1;
        }
    }
    for (i = 0; i < tree->node_count; i++)
        if (!seen[i]) {
            r = bvh__invalid(rep, i, "node not reachable from the root");
            goto done;
        }
    if (refs_seen != tree->ref_count) {
        r = bvh__invalid(rep, BVH_INVALID, "references not covered by exactly one leaf");
        goto done;
    }
    {
        uint32_t used_count = 0;
        for (i = 0; i < tree->prim_count; i++) used_count += used[i];
        if (used_count != tree->prim_count - tree->excluded) {
            r = bvh__invalid(rep, BVH_INVALID, "a primitive is not referenced by any leaf");
            goto done;
        }
    }
    if (tree->nodes8) r = bvh__validate_wide(tree, prim_boxes, splits, rep);
done:
    bvh__free(&al, seen);
    bvh__free(&al, used);
    bvh__free(&al, covered);
    return r;
}
BVH_API bvh_result bvh_validate(const bvh_tree *tree, const bvh_aabb *prim_boxes, bvh_validation *rep) {
    return bvh__validate(tree, prim_boxes, 0, rep);
}

/* ============================================================================================ */
/* == traversal ================================================================================= */
/* Watertight ray/triangle intersection (Woop, Benthin & Wald, JCGT 2013) in float, with their
   fallback to double where an edge function is zero, and robust slab tests (Ize 2013: the far
   distance is widened by 1 + 2 gamma(3)) so that no box rounding ever culls a triangle that the brute-force loop hits.
   A zero direction component (+0 or -0) gets an inverse of +inf; the NaN that appears when the
   origin lies on the slab plane is ignored by the min/max order, which is the right answer
   (the whole line is inside the slab). Near child first; any-hit stops at the first hit. */
/* ============================================================================================ */
typedef struct bvh__rayx {
    float o[3], d[3], inv[3], tmin; /* side by side: bvh__ray8_start copies them at once */
    int near[3];                    /* float offset in a node of the near plane on each axis: 0..2 min, 4..6 max */
    int near8[3], far8[3];          /* the same in a bvh_node8 (slot 0): 0, 8, 16 min, 24, 32, 40 max */
    int kx, ky, kz;                 /* watertight: kz = dominant axis (bvh__ray_setup); kx, ky and ... */
    float sx, sy, sz;               /* ... the shear are made by bvh__ray_shear before the first triangle test */
} bvh__rayx;
typedef char bvh__rayx_packed[offsetof(bvh__rayx, tmin) == 9 * sizeof(float) ? 1 : -1];

BVH__INLINE int bvh__ray_setup(const bvh_ray *ray, bvh__rayx *rx) {
    const float *o = &ray->origin.x, *d = &ray->dir.x;
    float ax, ay, az;
    int a;
    if (!bvh__finite3(o) || !bvh__finite3(d) || bvh__nan(ray->tmin) || bvh__nan(ray->tmax) || ray->tmin > ray->tmax)
        return 0;
    for (a = 0; a < 3; a++) {
        rx->o[a] = o[a];
        /* a subnormal component has no finite inverse: it is taken as 0 by the boxes and the
           triangles alike, so brute force and traversal agree */
        rx->d[a] = fabsf(d[a]) < FLT_MIN ? 0.0f : d[a];
        rx->inv[a] = rx->d[a] == 0.0f ? BVH_INF : 1.0f / rx->d[a];
        rx->near[a] = rx->inv[a] < 0.0f ? a + 4 : a;
        rx->near8[a] = rx->inv[a] < 0.0f ? 24 + 8 * a : 8 * a;
        rx->far8[a] = rx->inv[a] < 0.0f ? 8 * a : 24 + 8 * a;
    }
    if (rx->d[0] == 0.0f && rx->d[1] == 0.0f && rx->d[2] == 0.0f) return 0;
    d = rx->d;
    rx->tmin = ray->tmin;
    ax = fabsf(d[0]);
    ay = fabsf(d[1]);
    az = fabsf(d[2]);
    rx->kz = ax > ay ? (ax > az ? 0 : 2) : (ay > az ? 1 : 2);
    return 1;
}
/* kx, ky: the two axes after kz in cyclic order, swapped when d[kz] < 0 so that the winding is
   kept; [d[kz] < 0][kz], looked up: a branch on a random direction is a random branch. */
static const unsigned char bvh__kxy[2][3][2] = {{{1, 2}, {2, 0}, {0, 1}}, {{2, 1}, {0, 2}, {1, 0}}};
/* The rest of the watertight set-up (Woop et al.): the other two axes and the shear. Only the
   triangle test needs it, so the traversals make it when a ray first reaches a leaf: most rays
   of a frame miss after a box or two, and save its three divisions. */
BVH__INLINE void bvh__ray_shear(bvh__rayx *rx) {
    const float *d = rx->d;
    const unsigned char *k = bvh__kxy[d[rx->kz] < 0.0f][rx->kz];
    rx->kx = k[0];
    rx->ky = k[1];
    rx->sx = d[rx->kx] / d[rx->kz];
    rx->sy = d[rx->ky] / d[rx->kz];
    rx->sz = rx->inv[rx->kz]; /* 1 / d[kz], made by the set-up */
}

/* Returns 1 and sets *t, *u, *v if the triangle is hit with tmin <= t <= tmax, t finite.
   Float throughout, as Woop et al.: each vertex is translated and sheared once, so that the two
   triangles sharing an edge compute its edge function from the same floats, in mirrored order,
   and get exactly opposite values; rounding is monotone, so a float edge function never has the
   wrong sign, only a zero where the exact one is not. So a triangle with one edge function below
   zero and one above is missed whatever the exact values are, and is decided at once: that is
   most of the triangles a ray is tested against. Otherwise, where any of the three is zero, all
   three are redone in double from the sheared floats (products of two floats are exact in
   double), as Woop et al. do, so that the test stays watertight. The packet tests make the same
   operations in the same order on each lane, so all give the same bits. */
BVH__INLINE float bvh__slab(const bvh__rayx *r, const bvh_node *n, float tfar);
/* A zero-area triangle (exactly collinear or coincident vertices) is never hit. */
static int bvh__tri_zero_area(const float *tri) {
    double e1x = (double)tri[3] - tri[0], e1y = (double)tri[4] - tri[1], e1z = (double)tri[5] - tri[2];
    double e2x = (double)tri[6] - tri[0], e2y = (double)tri[7] - tri[1], e2z = (double)tri[8] - tri[2];
    return e1y * e2z - e1z * e2y == 0.0 && e1z * e2x - e1x * e2z == 0.0 && e1x * e2y - e1y * e2x == 0.0;
}
/* The ray must reach the triangle's own box by t, as the traversal's slab test sees it. Every
   node box that holds the triangle holds its box, and the slab test is monotone in the planes, so
   such a node is never culled before this hit. Only hits that precision made up fail: with an
   origin far from a large triangle, the float translation leaves the edge functions meaningless,
   and the test can report a hit far outside the triangle. */
static int bvh__tri_reach(const bvh__rayx *r, const float *tri, float t) {
    bvh_node box;
    bvh__set_box(&box, bvh__tri_box(tri));
    box.index = box.count = 0;
    return bvh__slab(r, &box, t) != BVH_INF;
}
/* The three edge functions of sheared vertices (x[i], y[i]) redone in double (bvh__tri_test). */
static void bvh__edges_exact(const float *x, const float *y, float *U, float *V, float *W) {
    *U = (float)((double)x[2] * y[1] - (double)y[2] * x[1]);
    *V = (float)((double)x[0] * y[2] - (double)y[0] * x[2]);
    *W = (float)((double)x[1] * y[0] - (double)y[1] * x[0]);
}
#ifdef BVH__SSE
/* bvh__edges_exact on the lanes of mask zm of a packet test of `w` lanes, whose sheared vertices
   are fx[k * w + lane], fy[k * w + lane] and edge functions fu/fv/fw[lane]. */
static void bvh__edges_exact_lanes(const float *fx, const float *fy, float *fu, float *fv, float *fw, unsigned zm,
                                   unsigned w) {
    float lx[3], ly[3];
    unsigned i, k;
    for (i = 0; i < w; i++) {
        if (!(zm >> i & 1u)) continue;
        for (k = 0; k < 3; k++) {
            lx[k] = fx[k * w + i];
            ly[k] = fy[k * w + i];
        }
        bvh__edges_exact(lx, ly, &fu[i], &fv[i], &fw[i]);
    }
}
#endif
/* Edge functions of both signs: the ray misses the triangle (see above). */
BVH__INLINE int bvh__edges_mixed(float U, float V, float W) {
    return (U < 0.0f || V < 0.0f || W < 0.0f) && (U > 0.0f || V > 0.0f || W > 0.0f);
}
BVH__INLINE int bvh__tri_test(const bvh__rayx *r, const float *tri, float tmax, float *t, float *u, float *v) {
    const int kx = r->kx, ky = r->ky, kz = r->kz;
    const float sx = r->sx, sy = r->sy, sz = r->sz;
    float x[3], y[3], z[3], U, V, W, det, T, ft;
    int k;
    for (k = 0; k < 3; k++) {
        z[k] = tri[3 * k + kz] - r->o[kz];
        x[k] = (tri[3 * k + kx] - r->o[kx]) - sx * z[k];
        y[k] = (tri[3 * k + ky] - r->o[ky]) - sy * z[k];
    }
    U = x[2] * y[1] - y[2] * x[1];
    V = x[0] * y[2] - y[0] * x[2];
    W = x[1] * y[0] - y[1] * x[0];
    if (bvh__edges_mixed(U, V, W)) return 0;
    if (U == 0.0f || V == 0.0f || W == 0.0f) {
        bvh__edges_exact(x, y, &U, &V, &W);
        if (bvh__edges_mixed(U, V, W)) return 0;
    }
    det = U + V + W;
    if (det == 0.0f) return 0;
    T = U * (sz * z[0]) + V * (sz * z[1]) + W * (sz * z[2]);
    ft = T / det;
    if (!(ft >= r->tmin && ft <= tmax && ft < BVH_INF)) return 0;
    if (bvh__tri_zero_area(tri) || !bvh__tri_reach(r, tri, ft)) return 0;
    *t = ft;
    *u = V / det;
    *v = W / det;
    return 1;
}

BVH_API int bvh_intersect_triangle(const bvh_ray *ray, const float v0[3], const float v1[3], const float v2[3],
                                   bvh_hit *hit) {
    bvh__rayx rx;
    float tri[9], t, u, v;
    if (hit) {
        hit->t = ray ? ray->tmax : BVH_INF;
        hit->u = hit->v = 0.0f;
        hit->prim = BVH_INVALID;
    }
    if (!ray || !v0 || !v1 || !v2 || !bvh__ray_setup(ray, &rx)) return 0;
    bvh__ray_shear(&rx);
    memcpy(tri, v0, 3 * sizeof(float));
    memcpy(tri + 3, v1, 3 * sizeof(float));
    memcpy(tri + 6, v2, 3 * sizeof(float));
    if (!bvh__tri_test(&rx, tri, ray->tmax, &t, &u, &v)) return 0;
    if (hit) {
        hit->t = t;
        hit->u = u;
        hit->v = v;
        hit->prim = 0;
    }
    return 1;
}

/* The slab test from the distances to the near (t0) and far (t1) planes on each axis: the entry
   distance if the ray enters before tfar, else +inf. bvh__slab4 does the same four lanes at a
   time. */
BVH__INLINE float bvh__slab_t(float tmin, int kz, float tfar, float t0x, float t1x, float t0y, float t1y, float t0z,
                              float t1z) {
    float tn = tmin, tf = BVH_INF, k0, k1, slack;
    tn = t0x > tn ? t0x : tn; /* NaN (origin on the plane) leaves tn as it is */
    tn = t0y > tn ? t0y : tn;
    tn = t0z > tn ? t0z : tn;
    tf = t1x < tf ? t1x : tf;
    tf = t1y < tf ? t1y : tf;
    tf = t1z < tf ? t1z : tf;
    tf *= 1.0000004f; /* 1 + 2 gamma(3) */
    /* A triangle inside the box has its watertight t computed with an error of a few ulps of its
       vertices' distances along the dominant axis, which the box's distances on that axis bound
       (t0 <= t1 there, so max(|t0|, |t1|) = max(t1, -t0)); lowering the entry by 2^-18 of those
       means a hit on the box's face is never culled. Selected without indexing, so that the
       distances stay in registers. */
    k0 = kz == 0 ? t0x : kz == 1 ? t0y : t0z;
    k1 = kz == 0 ? t1x : kz == 1 ? t1y : t1z;
    slack = k1 > -k0 ? k1 : -k0;
    tn -= slack * 3.814697265625e-6f; /* 2^-18 */
    /* But never below tmin: a box whose exit, rounded up, lies before tmin holds no exact hit at
       or after tmin, so it is skipped however near the origin it lies (a surface the ray leaves,
       an eye on a plane of box faces), and bvh__tri_reach, this test on the hit's own box, says
       the same of a hit that precision made up there. The slack stays for the entry of boxes
       ahead. (tn < tmin is false for a NaN, which then stays: not entered, as before.) */
    if (tn < tmin) tn = tmin;
    tf = tf < tfar ? tf : tfar;
    return tn <= tf ? tn : BVH_INF;
}
/* Entry distance of the ray into node n if it enters before tfar, else +inf. */
BVH__INLINE float bvh__slab(const bvh__rayx *r, const bvh_node *n, float tfar) {
    const float *f = &n->min.x; /* min at 0..2, max at 4..6 */
    return bvh__slab_t(r->tmin, r->kz, tfar, (f[r->near[0]] - r->o[0]) * r->inv[0],
                       (f[r->near[0] ^ 4] - r->o[0]) * r->inv[0], (f[r->near[1]] - r->o[1]) * r->inv[1],
                       (f[r->near[1] ^ 4] - r->o[1]) * r->inv[1], (f[r->near[2]] - r->o[2]) * r->inv[2],
                       (f[r->near[2] ^ 4] - r->o[2]) * r->inv[2]);
}

/* == 8-wide traversal layout =================================================================== */
/* bvh_build turns the binary tree into 8-wide nodes (tree.nodes8) whose leaves are packets of four
   triangles (tree.tri4). A wide node holds up to eight slots taken from the binary subtree below
   it: a cut of that subtree, the one of least expected cost (area times cost, summed over the
   wide nodes and leaf slots a ray enters), found by a dynamic program over the whole binary tree
   (Ylitie, Karras & Laine 2017, section 3.1; bvh__wide_prep). A leaf slot is a binary leaf, or
   a binary subtree of at most BVH__SLOT_REFS references: a node whose slots would all be such
   small leaves is a dependent load and 256 bytes for little culling, while a leaf of four packets
   is two passes of the AVX2 packet test on lines side by side, and its packets are fuller (a slot
   leaves at most three lanes empty, whatever its size); such a subtree may still be cut into
   smaller leaf slots where that costs less and needs no more packets (bvh__wide_cuttable: the
   layout's memory stays that of whole slots). The child boxes are
   the binary nodes' boxes, bit for bit, and the slab test below is the binary one lane by lane, so
   the argument that no box culls a hit the brute-force loop finds holds as it is; the packet test
   is bvh__tri_test lane by lane. The numbering depends on the tree alone, never on the thread count.
   Each wide node keeps its grouping (bvh_node8.head, .shape): the binary node it was made from, and
   the binary nodes from there down to its slots in pre-order (left child first), a bit each from
   bit 0 on: 1 a node opened inside the wide node, 0 a slot; at most 7 opened nodes and 8 slots, 15
   bits (a root that is a leaf slot: shape 0, its head its one slot). An opened leaf slot is one
   more opened node like any other. The slots are stored in the order any-hit rays take them: leaf
   slots first, largest box first, then the interior slots likeliest to stop a ray for what they
   cost (bvh__wide_slot_order; bvh_node8.order says where each of them, taken by ascending binary
   index, went). bvh_refit follows the grouping to
   update the boxes and packets in place (the order stays the build's), bvh_load to remake them
   from the saved binary tree; both check it against the binary tree as they go. */
#define BVH__PACKET 4u          /* triangles per packet */
#define BVH__SLOT_REFS 16u      /* a binary subtree of at most this many references is one leaf slot */
typedef struct bvh__wide_info { /* what the layout keeps of a binary node (see bvh__wide_prep) */
    uint32_t sub, cut;
    float cost, tarea;
} bvh__wide_info;
typedef struct bvh__wide_src {
    const bvh_node *nodes;
    const uint32_t *prims; /* the tree's references (caller ids) and their triangles */
    const float *tris;
    bvh_tri4 *packets;          /* NULL: count only */
    const bvh__wide_info *info; /* per binary node */
} bvh__wide_src;
BVH__INLINE int bvh__wide_leaf(const bvh__wide_src *s, uint32_t b) {
    return s->nodes[b].count || s->info[b].sub <= BVH__SLOT_REFS;
}
BVH__INLINE uint32_t bvh__wide_refs(const bvh__wide_src *s, uint32_t b) { return s->info[b].sub; }
BVH__INLINE uint32_t bvh__wide_packets(const bvh__wide_src *s, uint32_t b) {
    return (bvh__wide_refs(s, b) + BVH__PACKET - 1) / BVH__PACKET;
}
#ifdef BVH__SSE
/* Whether four triangles, by coordinate in lanes, all have a nonzero area that the double test
   below finds too, shown in float: a lane passes where a component of its cross product, e1y e2z
   - e1z e2y say, comes out above 2^-20 of s = |e1y e2z| + |e1z e2y| (all in float), with s at least
   2^-100. The float result is within 4 ulps' worth (2^-22) of s of the exact one (three
   roundings to the products, one to the difference; the edges, subnormal or not, are exact or
   within one rounding; below 2^-100 an underflow could hide more), so the exact component is
   above 2^-21 s, and the double test's, within 2^-51 s of the exact one, is not zero either. An
   overflow gives Inf or NaN, which pass nothing. A 0 says nothing: the double test decides. */
BVH__INLINE __m128 bvh__cross_nonzero(__m128 a, __m128 b, __m128 c, __m128 d) {
    const __m128 abs = _mm_castsi128_ps(_mm_set1_epi32(0x7fffffff));
    const __m128 p = _mm_mul_ps(a, b), q = _mm_mul_ps(c, d);
    const __m128 sum = _mm_add_ps(_mm_and_ps(p, abs), _mm_and_ps(q, abs));
    return _mm_and_ps(
        _mm_cmpgt_ps(_mm_and_ps(_mm_sub_ps(p, q), abs), _mm_mul_ps(sum, _mm_set1_ps(9.5367431640625e-7f))),
        _mm_cmpge_ps(sum, _mm_set1_ps(7.88860905221011805e-31f))); /* 2^-20, 2^-100 */
}
BVH__INLINE int bvh__area4_nonzero(__m128 x0, __m128 y0, __m128 z0, __m128 x1, __m128 y1, __m128 z1, __m128 x2,
                                   __m128 y2, __m128 z2) {
    const __m128 e1x = _mm_sub_ps(x1, x0), e1y = _mm_sub_ps(y1, y0), e1z = _mm_sub_ps(z1, z0);
    const __m128 e2x = _mm_sub_ps(x2, x0), e2y = _mm_sub_ps(y2, y0), e2z = _mm_sub_ps(z2, z0);
    const __m128 nz =
        _mm_or_ps(_mm_or_ps(bvh__cross_nonzero(e1y, e2z, e1z, e2y), bvh__cross_nonzero(e1z, e2x, e1x, e2z)),
                  bvh__cross_nonzero(e1x, e2y, e1y, e2x));
    return _mm_movemask_ps(nz) == 0xf;
}
/* Whether any of four triangles, by coordinate in lanes (x0 = the first vertices' x, ...), has
   zero area: bvh__tri_zero_area's double arithmetic, two lanes at a time, so the same answer. */
BVH__INLINE __m128d bvh__pd(__m128 v, int high) { return _mm_cvtps_pd(high ? _mm_movehl_ps(v, v) : v); }
static int bvh__any_zero_area4(__m128 x0, __m128 y0, __m128 z0, __m128 x1, __m128 y1, __m128 z1, __m128 x2, __m128 y2,
                               __m128 z2) {
    const __m128d zero = _mm_setzero_pd();
    int h, m = 0;
    if (bvh__area4_nonzero(x0, y0, z0, x1, y1, z1, x2, y2, z2)) return 0; /* nearly every packet */
    for (h = 0; h < 2; h++) {
        __m128d ax = bvh__pd(x0, h), ay = bvh__pd(y0, h), az = bvh__pd(z0, h);
        __m128d e1x = _mm_sub_pd(bvh__pd(x1, h), ax), e1y = _mm_sub_pd(bvh__pd(y1, h), ay);
        __m128d e1z = _mm_sub_pd(bvh__pd(z1, h), az), e2x = _mm_sub_pd(bvh__pd(x2, h), ax);
        __m128d e2y = _mm_sub_pd(bvh__pd(y2, h), ay), e2z = _mm_sub_pd(bvh__pd(z2, h), az);
        __m128d cx = _mm_sub_pd(_mm_mul_pd(e1y, e2z), _mm_mul_pd(e1z, e2y));
        __m128d cy = _mm_sub_pd(_mm_mul_pd(e1z, e2x), _mm_mul_pd(e1x, e2z));
        __m128d cz = _mm_sub_pd(_mm_mul_pd(e1x, e2y), _mm_mul_pd(e1y, e2x));
        m |= _mm_movemask_pd(
            _mm_and_pd(_mm_cmpeq_pd(cx, zero), _mm_and_pd(_mm_cmpeq_pd(cy, zero), _mm_cmpeq_pd(cz, zero))));
    }
    return m != 0;
}
#endif
/* The packets of n references (tree positions refs[], or 0 to n - 1 where refs is NULL; their
   triangles in tris, their primitives in prims, both by position), four to a packet.
   A packet with a zero-area triangle (flat) holds each such one as a point; the lanes past the
   references repeat lane 0, so they add no zero-area triangle of their own. With SSE the packets
   are streamed past the caches (non-temporal stores): the build, bvh_refit and bvh_load write
   them once and never read them back, and a store that misses would first read its line from
   memory (a 160-byte packet: two and a half lines read for nothing). The stores are weakly
   ordered: every thread that ran this fences them at the end of its team's pass
   (bvh__stream_fence, in the team's code), before any other thread may read the packets. */
static void bvh__packets_write(const uint32_t *refs, uint32_t n, const uint32_t *prims, const float *tris,
                               bvh_tri4 *out) {
    uint32_t i, j, v, a;
    for (i = 0; 4 * i < n; i++) {
        bvh_tri4 *p = &out[i];
        uint32_t lane[4];
        int flat = 0;
        for (j = 0; j < 4; j++) lane[j] = 4 * i + (4 * i + j < n ? j : 0);
        if (refs)
            for (j = 0; j < 4; j++) lane[j] = refs[lane[j]];
#ifdef BVH__SSE
        { /* the common case: a 4 x 9 transpose, the same floats */
            const float *t0 = tris + 9 * (size_t)lane[0], *t1 = tris + 9 * (size_t)lane[1];
            const float *t2 = tris + 9 * (size_t)lane[2], *t3 = tris + 9 * (size_t)lane[3];
            float *o = &p->v[0][0][0];
            __m128 a0 = _mm_loadu_ps(t0), a1 = _mm_loadu_ps(t1), a2 = _mm_loadu_ps(t2), a3 = _mm_loadu_ps(t3);
            __m128 b0 = _mm_loadu_ps(t0 + 4), b1 = _mm_loadu_ps(t1 + 4), b2 = _mm_loadu_ps(t2 + 4);
            __m128 b3 = _mm_loadu_ps(t3 + 4), c = _mm_setr_ps(t0[8], t1[8], t2[8], t3[8]);
            _MM_TRANSPOSE4_PS(a0, a1, a2, a3);
            _MM_TRANSPOSE4_PS(b0, b1, b2, b3);
            flat = bvh__any_zero_area4(a0, a1, a2, a3, b0, b1, b2, b3, c);
            if (!flat) {
                const __m128 rows[9] = {a0, a1, a2, a3, b0, b1, b2, b3, c};
                if (!((uintptr_t)(void *)p & 15u)) { /* streamed (see above) */
                    for (j = 0; j < 9; j++) _mm_stream_ps(o + 4 * j, rows[j]);
                    _mm_stream_si128(BVH__CAST(__m128i *, BVH__CAST(void *, p->prim)),
                                     _mm_setr_epi32((int)prims[lane[0]], (int)prims[lane[1]], (int)prims[lane[2]],
                                                    (int)prims[lane[3]]));
                } else { /* a block from an allocator that aligns less than malloc */
                    for (j = 0; j < 9; j++) _mm_storeu_ps(o + 4 * j, rows[j]);
                    for (j = 0; j < 4; j++) p->prim[j] = prims[lane[j]];
                }
                continue;
            }
        }
#else
        for (j = 0; j < 4; j++)
            flat |= (j == 0 || lane[j] != lane[0]) && bvh__tri_zero_area(tris + 9 * (size_t)lane[j]);
#endif
        for (j = 0; j < 4; j++) {
            uint32_t k = lane[j];
            const float *t = tris + 9 * (size_t)k;
            const int point = flat && bvh__tri_zero_area(t); /* held as its first vertex three times */
            for (v = 0; v < 3; v++)
                for (a = 0; a < 3; a++) p->v[v][a][j] = t[3 * (point ? 0 : v) + a];
            p->prim[j] = prims[k];
        }
    }
}
/* The packets of leaf slot b: its references in depth-first order, four to a packet. */
static void bvh__wide_write_packets(const bvh__wide_src *s, uint32_t b, bvh_tri4 *out) {
    uint32_t refs[BVH__MAX_LEAF], n = 0, stack[2 * BVH__SLOT_REFS], sp = 0, i;
    stack[sp++] = b;
    while (sp) { /* a subtree of at most BVH__SLOT_REFS references: fewer levels than that */
        const bvh_node *nd = &s->nodes[stack[--sp]];
        if (nd->count) {
            for (i = 0; i < nd->count; i++) refs[n++] = nd->index + i;
        } else {
            stack[sp++] = nd->index + 1;
            stack[sp++] = nd->index;
        }
    }
    bvh__packets_write(refs, n, s->prims, s->tris, out);
}
/* The shape of the wide node of head b whose slots are kids[0 .. k - 1] (see above). */
static uint32_t bvh__group_shape(const bvh_node *nodes, uint32_t b, const uint32_t *kids, uint32_t k) {
    uint32_t stack[BVH__W], sp = 0, bit = 0, shape = 0, i;
    stack[sp++] = b;
    while (sp) {
        uint32_t x = stack[--sp];
        for (i = 0; i < k && kids[i] != x; i++) {
        }
        if (i == k) { /* opened: its children follow, the left one first */
            shape |= 1u << bit;
            stack[sp++] = nodes[x].index + 1;
            stack[sp++] = nodes[x].index;
        }
        bit++;
    }
    return shape;
}
/* A wide node's grouping read back: its slots (ascending, the wide node's slot order) and the
   nodes opened in it (pre-order: parents before children). 0 where it does not fit the binary tree
   (an index out of range or not after its parent, an opened leaf, more than 8 slots, bits left
   over), so that a damaged tree is refused, never followed out of bounds. */
typedef struct bvh__group {
    uint32_t slot[BVH__W], open[BVH__W - 1], nslot, nopen;
} bvh__group;
static int bvh__group_read(const bvh_node *nodes, uint32_t node_count, const bvh_node8 *w, bvh__group *g) {
    uint32_t stack[BVH__W], sp = 0, bit = 0, i, a;
    if (w->head >= node_count) return 0;
    g->nslot = g->nopen = 0;
    stack[sp++] = w->head;
    while (sp) {
        uint32_t x = stack[--sp];
        if (bit == 15) return 0;
        if ((w->shape >> bit++) & 1u) {
            const bvh_node *n = &nodes[x];
            if (n->count || n->index <= x || n->index >= node_count - 1 || g->nopen == BVH__W - 1) return 0;
            g->open[g->nopen++] = x;
            stack[sp++] = n->index + 1;
            stack[sp++] = n->index;
        } else {
            if (g->nslot == BVH__W) return 0;
            g->slot[g->nslot++] = x;
        }
    }
    if (w->shape >> bit) return 0;
    for (i = 1; i < g->nslot; i++) /* insertion sort: ascending binary index */
        for (a = i; a > 0 && g->slot[a - 1] > g->slot[a]; a--) {
            uint32_t x = g->slot[a];
            g->slot[a] = g->slot[a - 1];
            g->slot[a - 1] = x;
        }
    for (i = 0, a = 0; i < BVH__W; i++) a |= w->order[i];
    if (a) { /* the build's slot order: a permutation of the first nslot, zero after them */
        uint32_t by[BVH__W], seen = 0;
        for (i = 0; i < BVH__W; i++) {
            if (i >= g->nslot ? w->order[i] != 0 : (w->order[i] >= g->nslot || (seen >> w->order[i]) & 1u)) return 0;
            if (i < g->nslot) {
                seen |= 1u << w->order[i];
                by[w->order[i]] = g->slot[i];
            }
        }
        for (i = 0; i < g->nslot; i++) g->slot[i] = by[i];
    }
    return 1;
}
/* Expected cost of a leaf slot of r references for a ray that enters its box: the leaf's set-up
   and one pass of the AVX2 test per two packets, in thirds of a pass. */
static float bvh__wide_leaf_cost(uint32_t r) {
    return 1.0f + 3.0f * (float)((r + 2u * BVH__PACKET - 1u) / (2u * BVH__PACKET));
}
static uint32_t bvh__wide_count_packets(uint32_t r) { return (r + BVH__PACKET - 1u) / BVH__PACKET; }
/* Whether an interior binary node of sub references, its children's subl and subr, may be opened
   inside a wide node: always, unless it may be a leaf slot and its children would need more
   packets than it (see the layout's comment above). */
static int bvh__wide_cuttable(uint32_t sub, uint32_t subl, uint32_t subr) {
    return sub > BVH__SLOT_REFS ||
           bvh__wide_count_packets(subl) + bvh__wide_count_packets(subr) <= bvh__wide_count_packets(sub);
}
/* A team of want threads, or of one where the team's bookkeeping cannot be allocated (a team
   fails before it runs anything, so fn runs once either way): for passes that must not fail
   half-way. */
static void bvh__team_run_always(const bvh_allocator *al, uint32_t want, bvh__team_fn fn, void *arg) {
    if (bvh__team_run(al, want, fn, arg) != BVH_SUCCESS) (void)bvh__team_run(al, 1, fn, arg);
}
/* The same on a caller's pool when there is one (it cannot fail): for the passes without
   barriers of bvh_refit and bvh_load. */
static void bvh__team_run_always_on(const bvh_thread_pool *pool, const bvh_allocator *al, uint32_t want,
                                    bvh__team_fn fn, void *arg) {
    if (pool && pool->run)
        (void)bvh__team_run_on(pool, al, want, 0, fn, arg);
    else
        bvh__team_run_always(al, want, fn, arg);
}
/* The first touch of a fresh block the library will fill, one byte a page, each thread of a team
   its own contiguous part: the kernel then clears the pages (a huge page's 2 MiB at a time) on
   every thread at once, rather than under a pass whose threads fill the block in interleaved
   pieces and wait on each other's faults there (bvh_load's 8-wide pass; docs/bench, 0.9.18). */
typedef struct bvh__touch_job {
    unsigned char *p;
    size_t size;
} bvh__touch_job;
static void bvh__touch_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    bvh__touch_job *j = BVH__CAST(bvh__touch_job *, arg);
    size_t b, e;
    (void)team;
    bvh__range(j->size, tid, nt, &b, &e);
    for (; b < e; b += 4096) j->p[b] = 0;
}
static void bvh__touch_pages(const bvh_thread_pool *pool, const bvh_allocator *al, uint32_t threads, void *p,
                             size_t size) {
    bvh__touch_job j;
    if (threads < 2 || !p) return;
    j.p = BVH__CAST(unsigned char *, p);
    j.size = size;
    bvh__team_run_always_on(pool, al, threads, bvh__touch_fn, &j);
}
/* The wide layout is made on the build's team: the top of the tree on one thread until there are
   BVH__WIDE_SUBTREES subtrees (bvh__wide_prep's binary subtrees, none split below
   BVH__WIDE_PREP_MIN nodes; bvh__wide_plan_make's wide subtrees), then those in parallel. */
#define BVH__WIDE_TOP 1024u
#define BVH__WIDE_SUBTREES 64u
#define BVH__WIDE_PREP_MIN 1024u
/* A wide node's test in those units: 4/3 of a pass (chosen from 3, 4, 5 and 6 by the bounce and
   shadow rays of three scenes; docs/bench 0.9.9). */
#define BVH__WIDE_NODE_COST 4.0f
/* The cut of least expected cost is Ylitie et al. 2017's dynamic program for wide BVHs over a
   row of eight costs a binary node: row[k - 1], the least expected cost (area x cost,
   bvh__wide_leaf_cost's units) of the node's subtree held in at most k slots of its parent's wide
   node: one slot (a leaf slot if the node may be one, else a wide node of its own:
   BVH__WIDE_NODE_COST plus its subtree in 8 slots), or the node opened and its two children
   sharing the k slots. A row is made from the children's rows alone, so the rows live on a stack
   while a walk takes the tree in post-order (bvh__wide_walk), and what the layout keeps of each
   binary node is bvh__wide_info:
   - sub: the references below it; tarea: their triangles' area (bvh__wide_slot_order);
   - cost: its row's first entry (one slot);
   - cut: 0 for a node that may not be opened (bvh__wide_cuttable); else, for each budget k of 2
     to 8 slots, four bits from bit 4 (k - 2): the left child's share of the k slots that gives
     the least cost (3 bits, the first of equals), and whether the node is opened with them (bit
     3: that costs strictly less than one slot). bvh__wide_gather replays these choices. (bvh__wide_info is declared
   with bvh__wide_src.) */
#define BVH__CUT_LEFT(w, k) (((w) >> (4u * ((k)-2u))) & 7u)
#define BVH__CUT_OPEN(w, k) (((w) >> (4u * ((k)-2u) + 3u)) & 1u)
#define BVH__WIDE_ITEMS (2u * BVH__WIDE_SUBTREES + 1u)
typedef struct bvh__wide_prep_job {
    const bvh_node *nodes;
    const float *tris; /* the tree's, by reference */
    bvh__wide_info *info;
    uint32_t count; /* binary nodes */
    /* the subtrees: root; [lo, hi), a guess of the range of its descendants (a builder writes
       them after it, in one range: bvh__emit), only to take the largest first; split: 0 for a
       worker's subtree, 1 for a root made here from its children's items, lo and lo + 1 */
    uint32_t item[BVH__WIDE_ITEMS][4];
    float row[BVH__WIDE_ITEMS][BVH__W]; /* each subtree root's row */
    uint32_t order[BVH__WIDE_ITEMS];    /* the split items, then the workers' items */
    uint32_t items, split, next;
    uint8_t bad[BVH__MAX_THREADS]; /* per thread: a node before its parent or too deep */
} bvh__wide_prep_job;
#ifdef BVH__SSE
/* bvh__wide_join's least cost of k slots shared out (d, four lanes of k - 1) and the left child's
   share that gives it (s, as a float), for one share more: the left child's cost l4 plus the
   right child's entries r shifted to the lanes they add up to (+inf where the right child gets
   none). Shares come in increasing order, so taking the later one is a maximum. */
#define BVH__SHL(v, n) _mm_castsi128_ps(_mm_slli_si128(_mm_castps_si128(v), n))
#define BVH__SHR(v, n) _mm_castsi128_ps(_mm_srli_si128(_mm_castps_si128(v), n))
BVH__INLINE void bvh__share_step(__m128 *d, __m128 *s, __m128 l4, __m128 r, __m128 share) {
    const __m128 v = _mm_add_ps(l4, r);
    *s = _mm_max_ps(*s, _mm_and_ps(_mm_cmplt_ps(v, *d), share));
    *d = _mm_min_ps(v, *d); /* v < d ? v : d */
}
#endif
/* A row of one slot whatever the budget: c in every entry, stored whole (read back in halves
   soon, bvh__wide_join). */
BVH__INLINE void bvh__wide_row_fill(float row[BVH__W], float c) {
#ifdef BVH__SSE
    _mm_storeu_ps(row, _mm_set1_ps(c));
    _mm_storeu_ps(row + 4, _mm_set1_ps(c));
#else
    uint32_t k;
    for (k = 0; k < BVH__W; k++) row[k] = c;
#endif
}
/* Leaf i's info and row. */
static void bvh__wide_leaf_row(const bvh__wide_prep_job *j, uint32_t i, float row[BVH__W]) {
    const bvh_node *n = &j->nodes[i];
    const float c = bvh_aabb_area(bvh__node_box(n)) * bvh__wide_leaf_cost(n->count);
    float sum = 0.0f; /* the triangles' area: a reference's whole triangle, also where clipped */
    uint32_t k;
    for (k = n->index; k < n->index + n->count; k++) {
        const float *v = j->tris + 9 * (size_t)k;
        const float ax = v[3] - v[0], ay = v[4] - v[1], az = v[5] - v[2];
        const float bx = v[6] - v[0], by = v[7] - v[1], bz = v[8] - v[2];
        const float cx = ay * bz - az * by, cy = az * bx - ax * bz, cz = ax * by - ay * bx;
        sum += 0.5f * sqrtf(cx * cx + cy * cy + cz * cz);
    }
    j->info[i].sub = n->count;
    j->info[i].cut = 0;
    j->info[i].cost = c;
    j->info[i].tarea = sum;
    bvh__wide_row_fill(row, c);
}
/* Interior node i's info and row (out) from its children's rows l and r (made before it, their
   infos too); out may be l or r. 0 where the references overflow. */
static int bvh__wide_join(const bvh__wide_prep_job *j, uint32_t i, const float *l, const float *r, float *out) {
    const bvh_node *n = &j->nodes[i];
    const bvh__wide_info *cl = &j->info[n->index], *cr = cl + 1;
    const float a = bvh_aabb_area(bvh__node_box(n));
    const uint32_t sub = cl->sub + cr->sub;
    const int cuttable = bvh__wide_cuttable(sub, cl->sub, cr->sub);
    float c0, d7;
    uint32_t cut = 0;
#ifdef BVH__SSE
    __m128 d0, d1;
    __m128i s0, s1;
#else
    float d[BVH__W];
    uint32_t k, left[BVH__W];
#endif
    if (sub < cl->sub) return 0;
    j->info[i].sub = sub;
    j->info[i].tarea = cl->tarea + cr->tarea;
    if (!cuttable) { /* one leaf slot whatever the budget (sub <= BVH__SLOT_REFS): no choice to make */
        j->info[i].cut = 0;
        j->info[i].cost = a * bvh__wide_leaf_cost(sub);
        bvh__wide_row_fill(out, j->info[i].cost);
        return 1;
    }
#ifdef BVH__SSE
    { /* lane k - 1 of d: the least cost of k slots shared out, the left child's share from 1 to
         k - 1, the first of equals (lane k - 1 of s); budget 1: none (+inf) */
        const __m128 r0 = _mm_loadu_ps(r), r1 = _mm_loadu_ps(r + 4), inf = _mm_set1_ps(BVH_INF);
        const __m128 i1 = _mm_setr_ps(BVH_INF, 0.0f, 0.0f, 0.0f), i2 = _mm_setr_ps(BVH_INF, BVH_INF, 0.0f, 0.0f);
        const __m128 i3 = _mm_setr_ps(BVH_INF, BVH_INF, BVH_INF, 0.0f);
        __m128 l4, f0 = _mm_set1_ps(1.0f), f1 = f0;
        d0 = d1 = inf;
        l4 = _mm_set1_ps(l[0]);
        bvh__share_step(&d0, &f0, l4, _mm_or_ps(BVH__SHL(r0, 4), i1), _mm_set1_ps(1.0f));
        bvh__share_step(&d1, &f1, l4, _mm_or_ps(BVH__SHL(r1, 4), BVH__SHR(r0, 12)), _mm_set1_ps(1.0f));
        l4 = _mm_set1_ps(l[1]);
        bvh__share_step(&d0, &f0, l4, _mm_or_ps(BVH__SHL(r0, 8), i2), _mm_set1_ps(2.0f));
        bvh__share_step(&d1, &f1, l4, _mm_or_ps(BVH__SHL(r1, 8), BVH__SHR(r0, 8)), _mm_set1_ps(2.0f));
        l4 = _mm_set1_ps(l[2]);
        bvh__share_step(&d0, &f0, l4, _mm_or_ps(BVH__SHL(r0, 12), i3), _mm_set1_ps(3.0f));
        bvh__share_step(&d1, &f1, l4, _mm_or_ps(BVH__SHL(r1, 12), BVH__SHR(r0, 4)), _mm_set1_ps(3.0f));
        /* shares 4 to 7 leave the right child no slot in lanes 0..3 */
        bvh__share_step(&d1, &f1, _mm_set1_ps(l[3]), r0, _mm_set1_ps(4.0f));
        bvh__share_step(&d1, &f1, _mm_set1_ps(l[4]), _mm_or_ps(BVH__SHL(r0, 4), i1), _mm_set1_ps(5.0f));
        bvh__share_step(&d1, &f1, _mm_set1_ps(l[5]), _mm_or_ps(BVH__SHL(r0, 8), i2), _mm_set1_ps(6.0f));
        bvh__share_step(&d1, &f1, _mm_set1_ps(l[6]), _mm_or_ps(BVH__SHL(r0, 12), i3), _mm_set1_ps(7.0f));
        s0 = _mm_cvttps_epi32(f0);
        s1 = _mm_cvttps_epi32(f1);
    }
#else
    { /* the same, lane by lane */
        uint32_t kl;
        for (k = 0; k < BVH__W; k++) {
            d[k] = BVH_INF;
            left[k] = 1;
        }
        for (kl = 1; kl < BVH__W; kl++)
            for (k = kl; k < BVH__W; k++) {
                const float v = l[kl - 1] + r[k - kl];
                const int less = v < d[k];
                d[k] = less ? v : d[k];
                left[k] = less ? kl : left[k];
            }
    }
#endif
#ifdef BVH__SSE
    d7 = _mm_cvtss_f32(_mm_shuffle_ps(d1, d1, 0xff));
#else
    d7 = d[BVH__W - 1];
#endif
    c0 = sub <= BVH__SLOT_REFS ? a * bvh__wide_leaf_cost(sub) : a * BVH__WIDE_NODE_COST + d7;
#ifdef BVH__SSE
    { /* the cut's nibbles: lane k's share and whether opened, lanes 1..7 to nibbles 0..6 */
        const __m128 c4 = _mm_set1_ps(c0);
        const __m128i eight = _mm_set1_epi32(8);
        const __m128i o0 = _mm_and_si128(_mm_castps_si128(_mm_cmplt_ps(d0, c4)), eight);
        const __m128i o1 = _mm_and_si128(_mm_castps_si128(_mm_cmplt_ps(d1, c4)), eight);
        const __m128i w = _mm_packs_epi32(_mm_or_si128(s0, o0), _mm_or_si128(s1, o1));
        uint64_t x;
        _mm_storel_epi64((__m128i *)(void *)&x, _mm_packus_epi16(w, w)); /* byte k: nibble of lane k */
        x >>= 8;
        x = (x | x >> 4) & 0x00ff00ff00ff00ffull;
        x = (x | x >> 8) & 0x0000ffff0000ffffull;
        cut = (uint32_t)(x | x >> 16);
    }
#else
    for (k = 1; k < BVH__W; k++) cut |= (left[k] | (uint32_t)(d[k] < c0) << 3) << (4 * (k - 1));
#endif
    j->info[i].cut = cut;
    j->info[i].cost = c0;
    /* the row: out[k] = min(out[k - 1], d[k]) from out[0] = c0 */
#ifdef BVH__SSE
    { /* the running minimum in registers, stored whole (a row is read back in halves soon) */
        const __m128 i1 = _mm_setr_ps(BVH_INF, 0.0f, 0.0f, 0.0f), i2 = _mm_setr_ps(BVH_INF, BVH_INF, 0.0f, 0.0f);
        __m128 lo = _mm_move_ss(d0, _mm_set_ss(c0)), hi = d1;
        lo = _mm_min_ps(lo, _mm_or_ps(BVH__SHL(lo, 4), i1));
        lo = _mm_min_ps(lo, _mm_or_ps(BVH__SHL(lo, 8), i2));
        hi = _mm_min_ps(hi, _mm_or_ps(BVH__SHL(hi, 4), i1));
        hi = _mm_min_ps(hi, _mm_or_ps(BVH__SHL(hi, 8), i2));
        hi = _mm_min_ps(hi, _mm_shuffle_ps(lo, lo, _MM_SHUFFLE(3, 3, 3, 3)));
        _mm_storeu_ps(out, lo);
        _mm_storeu_ps(out + 4, hi);
    }
#else
    out[0] = c0;
    for (k = 1; k < BVH__W; k++) out[k] = d[k] < out[k - 1] ? d[k] : out[k - 1];
#endif
    return 1;
}
/* The subtree of root in post-order (children before their parent, the left one first), its
   row into `row`: 0 where a node's children are not after it or the tree is deeper than a valid
   one can be. */
static int bvh__wide_walk(const bvh__wide_prep_job *j, uint32_t root, float row[BVH__W]) {
    uint32_t node[2 * (BVH_MAX_DEPTH + 2)], sp = 0, rp = 0;
    uint8_t opened[2 * (BVH_MAX_DEPTH + 2)];
    float rows[BVH_MAX_DEPTH + 2][BVH__W]; /* the rows made and not yet joined */
    node[sp] = root;
    opened[sp++] = 0;
    while (sp) {
        const uint32_t x = node[sp - 1];
        const bvh_node *n = &j->nodes[x];
        if (!n->count && !opened[sp - 1]) { /* its children first */
            if (n->index <= x || (uint64_t)n->index + 1 >= j->count || sp + 2 > 2 * (BVH_MAX_DEPTH + 2)) return 0;
            opened[sp - 1] = 1;
            node[sp] = n->index + 1;
            opened[sp++] = 0;
            node[sp] = n->index;
            opened[sp++] = 0;
            continue;
        }
        sp--;
        if (n->count) {
            if (rp == BVH_MAX_DEPTH + 2) return 0;
            bvh__wide_leaf_row(j, x, rows[rp++]);
        } else {
            rp -= 2;
            if (!bvh__wide_join(j, x, rows[rp], rows[rp + 1], rows[rp])) return 0;
            rp++;
        }
    }
    memcpy(row, rows[0], sizeof rows[0]);
    return 1;
}
/* The workers' subtrees, largest first. */
static void bvh__wide_prep_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    bvh__wide_prep_job *j = BVH__CAST(bvh__wide_prep_job *, arg);
    uint32_t k;
    (void)nt;
    (void)team;
    while (!j->bad[tid] && (k = __atomic_fetch_add(&j->next, 1u, __ATOMIC_RELAXED)) < j->items - j->split) {
        const uint32_t it = j->order[j->split + k];
        if (!bvh__wide_walk(j, j->item[it][0], j->row[it])) j->bad[tid] = 1;
    }
}
/* j->info for the tree of j->count nodes (a tree: bvh_build's or one bvh_load checked): the tree
   cut into subtrees, the largest first by its range's guess, until there are BVH__WIDE_SUBTREES;
   the subtrees walked on the team, the nodes above them here. The guesses only share out the
   work: the info is the same for any tree's layout and any team. */
static bvh_result bvh__wide_prep(bvh__wide_prep_job *j, const bvh_allocator *al, const bvh_thread_pool *pool,
                                 uint32_t threads) {
    const bvh_node *nodes = j->nodes;
    uint32_t i, k, nt;
    j->item[0][0] = 0;
    j->item[0][1] = 1;
    j->item[0][2] = j->count;
    j->item[0][3] = 0; /* the whole tree, the root's descendants after it */
    j->items = 1;
    j->split = 0;
    while (j->items - j->split < BVH__WIDE_SUBTREES && j->items + 2 <= BVH__WIDE_ITEMS) {
        uint32_t best = BVH_INVALID, size = BVH__WIDE_PREP_MIN, x, c, lo, hi, m;
        for (k = 0; k < j->items; k++)
            if (!j->item[k][3] && !nodes[j->item[k][0]].count && j->item[k][2] - j->item[k][1] >= size) {
                best = k;
                size = j->item[k][2] - j->item[k][1];
            }
        if (best == BVH_INVALID) break;
        x = j->item[best][0];
        c = nodes[x].index;
        if (c <= x || (uint64_t)c + 1 >= j->count) return BVH_ERROR_INVALID_TREE;
        hi = j->item[best][2];
        lo = c + 2 < hi ? c + 2 : hi;
        m = nodes[c + 1].count ? hi : nodes[c + 1].index; /* where the right child's range begins */
        m = m < lo ? lo : m > hi ? hi : m;
        j->item[j->items][0] = c;
        j->item[j->items][1] = lo;
        j->item[j->items][2] = m;
        j->item[j->items++][3] = 0;
        j->item[j->items][0] = c + 1;
        j->item[j->items][1] = m;
        j->item[j->items][2] = hi;
        j->item[j->items++][3] = 0;
        j->item[best][3] = 1;
        j->item[best][1] = j->items - 2;
        j->order[j->split++] = best;
    }
    for (k = 0, i = j->split; k < j->items; k++) /* the workers' items, largest range first */
        if (!j->item[k][3]) {
            const uint32_t size = j->item[k][2] - j->item[k][1];
            uint32_t a = i++;
            for (; a > j->split && j->item[j->order[a - 1]][2] - j->item[j->order[a - 1]][1] < size; a--)
                j->order[a] = j->order[a - 1];
            j->order[a] = k;
        }
    nt = j->count < 4 * BVH__WIDE_PREP_MIN ? 1 : threads < j->items - j->split ? threads : j->items - j->split;
    memset(j->bad, 0, sizeof j->bad);
    j->next = 0;
    if (pool && pool->run)
        (void)bvh__team_run_on(pool, al, nt, 0, bvh__wide_prep_fn, j);
    else
        bvh__team_run_always(al, nt, bvh__wide_prep_fn, j);
    for (i = 0; i < nt; i++)
        if (j->bad[i]) return BVH_ERROR_INVALID_TREE;
    for (k = j->split; k-- > 0;) { /* the nodes above the subtrees, children first */
        const uint32_t it = j->order[k], kid = j->item[it][1];
        if (!bvh__wide_join(j, j->item[it][0], j->row[kid], j->row[kid + 1], j->row[it])) return BVH_ERROR_INVALID_TREE;
    }
    return BVH_SUCCESS;
}
/* The slots of interior binary node b, opened as the head of a wide node: the cut of least cost
   (bvh__wide_prep's choices), the eight slots shared out between its children and on down, a
   node opened only where that costs strictly less than one slot (ties: fewer slots). */
static uint32_t bvh__wide_gather(const bvh__wide_src *s, uint32_t b, uint32_t out[BVH__W]) {
    uint32_t todo[BVH__W][2], n = 0, k = 0, kl = BVH__CUT_LEFT(s->info[b].cut, BVH__W);
    todo[n][0] = s->nodes[b].index + 1;
    todo[n++][1] = BVH__W - kl;
    todo[n][0] = s->nodes[b].index;
    todo[n++][1] = kl;
    while (n) {
        const uint32_t x = todo[--n][0], budget = todo[n][1];
        if (budget > 1 && BVH__CUT_OPEN(s->info[x].cut, budget)) { /* opened: its children share the budget */
            kl = BVH__CUT_LEFT(s->info[x].cut, budget);
            todo[n][0] = s->nodes[x].index + 1;
            todo[n++][1] = budget - kl;
            todo[n][0] = s->nodes[x].index;
            todo[n++][1] = kl;
            continue;
        }
        out[k++] = x;
    }
    return k;
}
/* A wide node with no slot filled: links zero, every box empty (+inf min, -inf max), which no
   ray enters. */
static void bvh__node8_clear(bvh_node8 *w) {
    uint32_t i, a;
    memset(w, 0, sizeof *w);
    for (i = 0; i < BVH__W; i++)
        for (a = 0; a < 3; a++) {
            w->min[a][i] = BVH_INF;
            w->max[a][i] = -BVH_INF;
        }
}
/* Slot i's box. */
BVH__INLINE void bvh__node8_box(bvh_node8 *w, uint32_t i, bvh_vec3 lo, bvh_vec3 hi) {
    w->min[0][i] = lo.x;
    w->min[1][i] = lo.y;
    w->min[2][i] = lo.z;
    w->max[0][i] = hi.x;
    w->max[1][i] = hi.y;
    w->max[2][i] = hi.z;
}
/* Slots kids[0 .. k - 1] (ascending binary index) put in the order an any-hit ray takes a node's
   entered slots: leaf slots first (entering one tests its triangles at once, an interior slot
   costs another node before any), largest box first (a larger box is likelier to hold what
   blocks the ray); then the interior slots by the chance that their subtree stops a ray that
   enters it over what the subtree costs that ray, highest first (Ize & Hansen 2011's ordering
   for shadow rays): the chance is the triangles' area over half the box's (a flat triangle
   inside a convex box is crossed by that fraction of the lines through the box, by Crofton's
   formula; the sum, capped at 1, counts overlaps twice), the cost is the subtree's expected
   cost per ray that enters it (bvh__wide_prep's table over the box's area). Ties: the lower
   index. order, when given, gets where each went (bvh_node8.order), so that bvh__group_read finds
   the slots from the grouping alone. */
static void bvh__wide_slot_order(const bvh__wide_src *s, uint32_t kids[BVH__W], uint32_t k, uint8_t *order) {
    uint32_t i, j, by[BVH__W];
    uint64_t key[BVH__W];
    for (i = 0; i < k; i++) { /* the order as one number, larger first: leaf, key's bits, index */
        const float a = bvh_aabb_area(bvh__node_box(&s->nodes[kids[i]]));
        const int leaf = bvh__wide_leaf(s, kids[i]);
        float f = a > 0.0f ? a : a == 0.0f ? 0.0f : BVH_INF; /* NaN (0 x inf on huge boxes) as +inf */
        uint32_t bits;
        if (!leaf) {
            const float chance = 2.0f * s->info[kids[i]].tarea / a, cost = s->info[kids[i]].cost / a;
            f = (chance < 1.0f ? chance : 1.0f) / cost;
            if (!(f > 0.0f)) f = 0.0f; /* a flat box (0 / 0): last */
        }
        memcpy(&bits, &f, sizeof bits); /* a float >= +0 orders as its bits */
        key[i] = (uint64_t)leaf << 63 | (uint64_t)bits << 3 | (BVH__W - 1 - i);
    }
    for (i = 0; i < k; i++) { /* slot of kids[i]: the count of those before it in the order */
        uint32_t at = 0;
        for (j = 0; j < k; j++) at += key[j] > key[i];
        by[at] = kids[i];
        if (order) order[i] = (uint8_t)at;
    }
    for (i = 0; i < k; i++) kids[i] = by[i];
}
/* Fills wide node `out` (when not NULL) from binary head b and returns its child count; kids[]
   gets the binary children in slot order (bvh__wide_slot_order). Leaf slots
   take their packets from *packet on (written when s->packets is set). */
/* The slots of the wide node of binary head b, in the gather's order; returns their count. */
static uint32_t bvh__wide_slots(const bvh__wide_src *s, uint32_t b, uint32_t kids[BVH__W]) {
    if (!bvh__wide_leaf(s, b)) return bvh__wide_gather(s, b, kids);
    kids[0] = b; /* a root that is a leaf slot */
    return 1;
}
static uint32_t bvh__wide_node(const bvh__wide_src *s, uint32_t b, bvh_node8 *out, uint32_t kids[BVH__W],
                               uint32_t *packet) {
    uint32_t k = bvh__wide_slots(s, b, kids), i, a;
    if (s->packets)
        for (i = 0; i < k; i++) /* the leaf slots' triangles asked for ahead */
            if (bvh__wide_leaf(s, kids[i])) {
                const bvh_node *nd = &s->nodes[kids[i]];
                const char *t, *e;
                while (!nd->count) nd = &s->nodes[nd->index];
                t = (const char *)(s->tris + 9 * (size_t)nd->index);
                for (e = t + 36 * (size_t)bvh__wide_refs(s, kids[i]); t < e; t += 64) BVH__PREFETCH(t);
            }
    for (i = 1; i < k; i++)
        for (a = i; a > 0 && kids[a - 1] > kids[a]; a--) {
            uint32_t x = kids[a];
            kids[a] = kids[a - 1];
            kids[a - 1] = x;
        }
    if (out) {
        bvh__node8_clear(out);
        out->head = b;
        out->shape = bvh__group_shape(s->nodes, b, kids, k);
    }
    bvh__wide_slot_order(s, kids, k, out ? out->order : NULL);
    for (i = 0; i < k; i++) {
        const bvh_node *c = &s->nodes[kids[i]];
        if (out) bvh__node8_box(out, i, c->min, c->max);
        if (!bvh__wide_leaf(s, kids[i])) continue; /* interior children: the caller sets the index */
        if (out) {
            out->child[i] = *packet;
            out->count[i] = (uint8_t)bvh__wide_packets(s, kids[i]);
        }
        if (s->packets) bvh__wide_write_packets(s, kids[i], s->packets + *packet);
        *packet += bvh__wide_packets(s, kids[i]);
    }
    return k;
}
/* The wide subtree of binary head b, numbered from w on in depth-first order with the children of
   a node side by side, its packets from *packet on; counts only when out is NULL. Returns the node
   count, 0 if the tree is deeper than a valid one can be. */
static uint32_t bvh__wide_subtree(const bvh__wide_src *s, uint32_t b, bvh_node8 *out, uint32_t w, uint32_t *packet) {
    uint32_t stack[BVH__W * (BVH_MAX_DEPTH + 2)][2], sp = 0, next = w + 1;
    stack[sp][0] = b;
    stack[sp][1] = w;
    sp++;
    while (sp) {
        uint32_t kids[BVH__W], k, i, top;
        bvh_node8 *n;
        --sp;
        n = out ? &out[stack[sp][1]] : NULL;
        if (n) {
            k = bvh__wide_node(s, stack[sp][0], n, kids, packet);
        } else { /* counting: the slots in any order */
            k = bvh__wide_slots(s, stack[sp][0], kids);
            for (i = 0; i < k; i++)
                if (bvh__wide_leaf(s, kids[i])) *packet += bvh__wide_packets(s, kids[i]);
        }
        for (i = k; i-- > 0;) /* interior children pushed last to first: the first is read next */
            if (!bvh__wide_leaf(s, kids[i])) {
                if (sp == BVH__W * (BVH_MAX_DEPTH + 2)) return 0;
                stack[sp++][0] = kids[i];
            }
        for (i = 0, top = sp; i < k; i++)
            if (!bvh__wide_leaf(s, kids[i])) {
                stack[--top][1] = next;
                if (n) n->child[i] = next;
                next++;
            }
    }
    return next - w;
}
/* Wide nodes on the build's team: the first levels breadth-first on one thread until there are
   BVH__WIDE_SUBTREES subtrees, then the subtrees counted, and written, in parallel, each numbered
   after the ones before it. The split depends on the tree alone, never on the thread count, so
   the numbering is the same for any team. */
typedef struct bvh__wide_job {
    bvh__wide_src src;
    bvh_node8 *out;
    const uint32_t *heads; /* binary heads of the subtrees */
    uint32_t *size;        /* wide nodes per subtree; for the write pass, their first index */
    uint32_t *psize;       /* packets per subtree; for the write pass, their first index */
    const uint32_t *order; /* the write pass's order of the subtrees: most packets first */
    uint32_t count, next;
} bvh__wide_job;
static void bvh__wide_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    bvh__wide_job *j = BVH__CAST(bvh__wide_job *, arg);
    uint32_t k;
    (void)tid;
    (void)nt;
    (void)team;
    while ((k = __atomic_fetch_add(&j->next, 1u, __ATOMIC_RELAXED)) < j->count) {
        const uint32_t i = j->out ? j->order[k] : k;
        uint32_t p = j->out ? j->psize[i] : 0;
        if (j->out) {
            bvh__wide_subtree(&j->src, j->heads[i], j->out, j->size[i], &p);
        } else {
            j->size[i] = bvh__wide_subtree(&j->src, j->heads[i], NULL, 0, &p);
            j->psize[i] = p;
        }
    }
}
/* The wide layout in two passes: the plan (the breadth-first top and every subtree's node and
   packet counts, hence the totals) and the write pass into arrays of those sizes. */
typedef struct bvh__wide_plan {
    uint32_t queue[BVH__WIDE_TOP], size[BVH__WIDE_TOP], psize[BVH__WIDE_TOP], order[BVH__WIDE_TOP], qlen, top;
    uint32_t nodes, packets, nt; /* totals; the team's size */
    const bvh_thread_pool *pool; /* the build's pool (NULL: the library's threads) */
    bvh__wide_job job;
} bvh__wide_plan;
/* The same on the build's pool when there is one (a pool's run cannot fail). */
static void bvh__wide_run(const bvh__wide_plan *p, const bvh_allocator *al, bvh__wide_job *job) {
    if (p->pool && p->pool->run)
        (void)bvh__team_run_on(p->pool, al, p->nt, 0, bvh__wide_fn, job);
    else
        bvh__team_run_always(al, p->nt, bvh__wide_fn, job);
}
static void bvh__wide_plan_init(bvh__wide_plan *p, const bvh_tree *tree, const bvh__wide_info *info) {
    memset(&p->job, 0, sizeof p->job);
    p->job.src.nodes = tree->nodes;
    p->job.src.info = info;
    p->job.src.prims = tree->prims;
    p->job.src.tris = tree->tris;
    p->pool = NULL;
    p->job.size = p->size;
    p->job.psize = p->psize;
    p->job.order = p->order;
}
/* The plan of tree's wide layout from bvh__wide_prep's info: the build's. */
static bvh_result bvh__wide_plan_make(bvh__wide_plan *p, const bvh_tree *tree, const bvh__wide_info *info,
                                      const bvh_allocator *al, const bvh_thread_pool *pool, uint32_t threads) {
    uint32_t i, k, total, ptotal = 0, kids[BVH__W];
    bvh__wide_plan_init(p, tree, info);
    p->pool = pool;
    p->queue[0] = 0;
    p->qlen = 1;
    p->top = 0;
    while (p->top < p->qlen && p->qlen - p->top < BVH__WIDE_SUBTREES &&
           p->qlen + BVH__W <= BVH__WIDE_TOP) { /* breadth-first top */
        k = bvh__wide_node(&p->job.src, p->queue[p->top++], NULL, kids, &ptotal);
        for (i = 0; i < k; i++)
            if (!bvh__wide_leaf(&p->job.src, kids[i])) p->queue[p->qlen++] = kids[i];
    }
    p->job.heads = p->queue + p->top;
    p->job.count = p->qlen - p->top;
    p->nt = threads < p->job.count ? threads : p->job.count;
    if (p->job.count) bvh__wide_run(p, al, &p->job);
    for (i = 0; i < p->job.count; i++) { /* the write pass's order: most packets first */
        uint32_t a;
        for (a = i; a > 0 && p->psize[p->order[a - 1]] < p->psize[i]; a--) p->order[a] = p->order[a - 1];
        p->order[a] = i;
    }
    for (i = 0, total = p->top; i < p->job.count; i++) {
        uint32_t s = p->size[i], c = p->psize[i];
        if (!s || s > 0xffffffffu - total || c > 0xffffffffu - ptotal) return BVH_ERROR_INVALID_TREE;
        p->size[i] = total;
        total += s;
        p->psize[i] = ptotal;
        ptotal += c;
    }
    p->nodes = total;
    p->packets = ptotal;
    return BVH_SUCCESS;
}
/* The write pass of a plan into nodes8 (p->nodes nodes) and tri4 (p->packets packets). */
static void bvh__wide_write(bvh__wide_plan *p, bvh_node8 *nodes8, bvh_tri4 *tri4, const bvh_allocator *al) {
    uint32_t i, k, pos, ptotal = 0, kids[BVH__W];
    p->job.src.packets = tri4;
    for (i = 0, pos = 1; i < p->top; i++) { /* the top, numbered in the order of the queue */
        bvh_node8 *n = &nodes8[i];
        uint32_t j;
        k = bvh__wide_node(&p->job.src, p->queue[i], n, kids, &ptotal);
        for (j = 0; j < k; j++)
            if (!bvh__wide_leaf(&p->job.src, kids[j])) {
                n->child[j] = pos < p->top ? pos : p->size[pos - p->top];
                pos++;
            }
    }
    bvh__stream_fence(); /* the top's packets */
    p->job.out = nodes8;
    p->job.next = 0;
    if (p->job.count) bvh__wide_run(p, al, &p->job);
}
/* One block for both arrays: the packets follow the nodes, on a cache line as well (256-byte
   nodes). */
static bvh_result bvh__wide_alloc(bvh_tree *tree, const bvh_allocator *al, uint32_t nodes, uint32_t packets) {
    if ((size_t)packets + 1 > ((size_t)-1 - (size_t)nodes * sizeof(bvh_node8)) / sizeof(bvh_tri4))
        return BVH_ERROR_OUT_OF_MEMORY;
    tree->nodes8 = BVH__CAST(bvh_node8 *, bvh__alloc_lines(al, (size_t)nodes * sizeof(bvh_node8) +
                                                                   (size_t)(packets ? packets : 1) * sizeof(bvh_tri4)));
    if (!tree->nodes8) return BVH_ERROR_OUT_OF_MEMORY;
    tree->tri4 = BVH__CAST(bvh_tri4 *, BVH__CAST(void *, tree->nodes8 + nodes));
    tree->node8_count = nodes;
    tree->tri4_count = packets;
    return BVH_SUCCESS;
}
static bvh_result bvh__make_wide(bvh_tree *tree, const bvh_allocator *al, const bvh_thread_pool *pool,
                                 uint32_t threads) {
    bvh__wide_plan *p;
    bvh__wide_prep_job *t;
    bvh_result r;
    if (!tree->node_count) return BVH_SUCCESS;
    p = BVH__ALLOC(al, bvh__wide_plan, 1); /* 16 KiB and 7 KiB: off the stack */
    t = BVH__ALLOC(al, bvh__wide_prep_job, 1);
    if (t) {
        t->nodes = tree->nodes;
        t->tris = tree->tris;
        t->count = tree->node_count;
        t->info = BVH__ALLOC(al, bvh__wide_info, tree->node_count);
    }
    if (!p || !t || !t->info) {
        r = BVH_ERROR_OUT_OF_MEMORY;
        goto done;
    }
    if ((r = bvh__wide_prep(t, al, pool, threads)) != BVH_SUCCESS ||
        (r = bvh__wide_plan_make(p, tree, t->info, al, pool, threads)) != BVH_SUCCESS ||
        (r = bvh__wide_alloc(tree, al, p->nodes, p->packets)) != BVH_SUCCESS)
        goto done;
    bvh__wide_write(p, tree->nodes8, tree->tri4, al);
done:
    if (t) bvh__free(al, t->info);
    bvh__free(al, t);
    bvh__free(al, p);
    return r;
}

#ifndef BVH__SSE
/* Entry distances of the ray into the eight child boxes of n (mask bit i: slot i entered before
   tfar); the binary bvh__slab, lane by lane. */
BVH__INLINE unsigned bvh__slab8(const bvh__rayx *r, const bvh_node8 *n, float tfar, float tn_out[BVH__W]) {
    const float *f = &n->min[0][0];
    unsigned mask = 0, i;
    for (i = 0; i < BVH__W; i++) { /* the node's lanes: an empty slot gives +inf */
        tn_out[i] = bvh__slab_t(r->tmin, r->kz, tfar, (f[r->near8[0] + i] - r->o[0]) * r->inv[0],
                                (f[r->far8[0] + i] - r->o[0]) * r->inv[0], (f[r->near8[1] + i] - r->o[1]) * r->inv[1],
                                (f[r->far8[1] + i] - r->o[1]) * r->inv[1], (f[r->near8[2] + i] - r->o[2]) * r->inv[2],
                                (f[r->far8[2] + i] - r->o[2]) * r->inv[2]);
        if (tn_out[i] != BVH_INF) mask |= 1u << i;
    }
    return mask;
}
#endif

/* The closest (or, with any, the first) hit so far. */
typedef struct bvh__best {
    float t, u, v;
    uint32_t prim;
    const bvh_tri4 *pk; /* the wide traversal's: the hit's packet and lane (its vertices, in cache) */
    uint32_t lane;
} bvh__best;
typedef struct bvh__entry8 {
    uint32_t child, count;
    float t;
} bvh__entry8;
#if defined(__GNUC__) || defined(__clang__)
#define BVH__CTZ(m) ((unsigned)__builtin_ctz(m))
#define BVH__TOP_BIT(m) (31u - (unsigned)__builtin_clz(m)) /* the highest set bit's index */
#else
static unsigned bvh__ctz(unsigned m) {
    unsigned i = 0;
    while (!(m & 1u)) {
        m >>= 1;
        i++;
    }
    return i;
}
#define BVH__CTZ(m) bvh__ctz(m)
static unsigned bvh__top_bit(unsigned m) {
    unsigned i = 0;
    while (m >>= 1) i++;
    return i;
}
#define BVH__TOP_BIT(m) bvh__top_bit(m)
#endif
/* The packet test: bvh__tri_test on the four lanes at once, the same operations in the same order
   on each lane, so the same bits. Most packets end at the sign test; the distance, the division
   and the triangle-box check (bvh__tri_reach, here on all lanes at once) follow only where a lane
   passes it. No zero-area check: the packets hold such a triangle as one point repeated, whose
   edge functions are all exactly zero, so det = 0 and no ray hits it, as bvh__tri_test says. */
#ifdef BVH__SSE
/* bvh__slab_t on four boxes (lo, hi by axis) with a distance limit per lane: 1 where entered. */
BVH__INLINE unsigned bvh__reach4(const bvh__rayx *r, const __m128 lo[3], const __m128 hi[3], __m128 t) {
    __m128 tn = _mm_set1_ps(r->tmin), tf = _mm_set1_ps(BVH_INF), t0[3], t1[3], slack;
    int a;
    for (a = 0; a < 3; a++) {
        const __m128 o = _mm_set1_ps(r->o[a]), inv = _mm_set1_ps(r->inv[a]);
        const int neg = r->inv[a] < 0.0f;
        t0[a] = _mm_mul_ps(_mm_sub_ps(neg ? hi[a] : lo[a], o), inv);
        t1[a] = _mm_mul_ps(_mm_sub_ps(neg ? lo[a] : hi[a], o), inv);
        tn = _mm_max_ps(t0[a], tn);
        tf = _mm_min_ps(t1[a], tf);
    }
    tf = _mm_mul_ps(tf, _mm_set1_ps(1.0000004f));
    slack = _mm_max_ps(t1[r->kz], _mm_sub_ps(_mm_setzero_ps(), t0[r->kz]));
    tn = _mm_sub_ps(tn, _mm_mul_ps(slack, _mm_set1_ps(3.814697265625e-6f)));
    tn = _mm_max_ps(_mm_set1_ps(r->tmin), tn); /* never below tmin (bvh__slab_t); a NaN stays */
    tf = _mm_min_ps(tf, t);
    return (unsigned)_mm_movemask_ps(_mm_cmple_ps(tn, tf));
}
/* The lanes of mask m that hit (bvh__tri_test's checks after the sign test); *ft their t. */
BVH__INLINE unsigned bvh__packet_hits(const bvh__rayx *r, const bvh_tri4 *p, __m128 U, __m128 V, __m128 W,
                                      const __m128 z[3], float tmax, unsigned m, __m128 *ft, __m128 *det) {
    const __m128 sz = _mm_set1_ps(r->sz);
    __m128 T, lo[3], hi[3], ok;
    int a;
    *det = _mm_add_ps(_mm_add_ps(U, V), W);
    T = _mm_add_ps(_mm_add_ps(_mm_mul_ps(U, _mm_mul_ps(sz, z[0])), _mm_mul_ps(V, _mm_mul_ps(sz, z[1]))),
                   _mm_mul_ps(W, _mm_mul_ps(sz, z[2])));
    *ft = _mm_div_ps(T, *det);
    ok = _mm_and_ps(_mm_cmpge_ps(*ft, _mm_set1_ps(r->tmin)), _mm_cmple_ps(*ft, _mm_set1_ps(tmax)));
    ok = _mm_and_ps(ok, _mm_cmplt_ps(*ft, _mm_set1_ps(BVH_INF)));
    ok = _mm_and_ps(ok, _mm_cmpneq_ps(*det, _mm_setzero_ps()));
    m &= (unsigned)_mm_movemask_ps(ok);
    if (!m) return 0;
    for (a = 0; a < 3; a++) { /* the triangles' boxes (bvh__tri_box) */
        const __m128 v0 = _mm_loadu_ps(p->v[0][a]), v1 = _mm_loadu_ps(p->v[1][a]), v2 = _mm_loadu_ps(p->v[2][a]);
        lo[a] = _mm_min_ps(_mm_min_ps(v0, v1), v2);
        hi[a] = _mm_max_ps(_mm_max_ps(v0, v1), v2);
    }
    return m & bvh__reach4(r, lo, hi, *ft);
}
BVH__INLINE float bvh__lane_f(__m128 x, unsigned i) {
    float f[4];
    _mm_storeu_ps(f, x);
    return f[i];
}
/* bvh__edges_mixed on four lanes: bit i set where lane i's edge functions have both signs. */
BVH__INLINE unsigned bvh__edges_mixed4(__m128 U, __m128 V, __m128 W) {
    const __m128 zero = _mm_setzero_ps();
    const __m128 neg = _mm_or_ps(_mm_or_ps(_mm_cmplt_ps(U, zero), _mm_cmplt_ps(V, zero)), _mm_cmplt_ps(W, zero));
    const __m128 pos = _mm_or_ps(_mm_or_ps(_mm_cmpgt_ps(U, zero), _mm_cmpgt_ps(V, zero)), _mm_cmpgt_ps(W, zero));
    return (unsigned)_mm_movemask_ps(_mm_and_ps(neg, pos));
}
static int bvh__packets(const bvh__rayx *r, const bvh_tri4 *p, uint32_t np, bvh__best *b, int any) {
    const int kx = r->kx, ky = r->ky, kz = r->kz;
    const __m128 ox = _mm_set1_ps(r->o[kx]), oy = _mm_set1_ps(r->o[ky]), oz = _mm_set1_ps(r->o[kz]);
    const __m128 sx = _mm_set1_ps(r->sx), sy = _mm_set1_ps(r->sy), zero = _mm_setzero_ps();
    uint32_t q;
    int found = 0;
    for (q = 0; q < np; q++, p++) {
        __m128 x[3], y[3], z[3], U, V, W, ft, det;
        unsigned m, zm;
        int k;
        for (k = 0; k < 3; k++) {
            z[k] = _mm_sub_ps(_mm_loadu_ps(p->v[k][kz]), oz);
            x[k] = _mm_sub_ps(_mm_sub_ps(_mm_loadu_ps(p->v[k][kx]), ox), _mm_mul_ps(sx, z[k]));
            y[k] = _mm_sub_ps(_mm_sub_ps(_mm_loadu_ps(p->v[k][ky]), oy), _mm_mul_ps(sy, z[k]));
        }
        U = _mm_sub_ps(_mm_mul_ps(x[2], y[1]), _mm_mul_ps(y[2], x[1]));
        V = _mm_sub_ps(_mm_mul_ps(x[0], y[2]), _mm_mul_ps(y[0], x[2]));
        W = _mm_sub_ps(_mm_mul_ps(x[1], y[0]), _mm_mul_ps(y[1], x[0]));
        m = 15u & ~bvh__edges_mixed4(U, V, W);
        if (!m) continue;
        zm = m & (unsigned)_mm_movemask_ps(
                     _mm_or_ps(_mm_or_ps(_mm_cmpeq_ps(U, zero), _mm_cmpeq_ps(V, zero)), _mm_cmpeq_ps(W, zero)));
        if (zm) { /* the lanes left with a zero edge function, redone in double */
            float fx[3][4], fy[3][4], fu[4], fv[4], fw[4];
            for (k = 0; k < 3; k++) {
                _mm_storeu_ps(fx[k], x[k]);
                _mm_storeu_ps(fy[k], y[k]);
            }
            _mm_storeu_ps(fu, U);
            _mm_storeu_ps(fv, V);
            _mm_storeu_ps(fw, W);
            bvh__edges_exact_lanes(&fx[0][0], &fy[0][0], fu, fv, fw, zm, 4);
            U = _mm_loadu_ps(fu);
            V = _mm_loadu_ps(fv);
            W = _mm_loadu_ps(fw);
            m &= ~bvh__edges_mixed4(U, V, W);
            if (!m) continue;
        }
        m = bvh__packet_hits(r, p, U, V, W, z, b->t, m, &ft, &det);
        if (!m) continue;
        if (any) {
            b->t = bvh__lane_f(ft, BVH__CTZ(m));
            b->prim = p->prim[BVH__CTZ(m)];
            b->pk = p;
            b->lane = BVH__CTZ(m);
            return 1;
        }
        while (m) { /* the nearest lane; ties in t: the lowest primitive index */
            unsigned i = BVH__CTZ(m);
            float t = bvh__lane_f(ft, i), d = bvh__lane_f(det, i);
            m &= m - 1;
            if (t > b->t || (t == b->t && p->prim[i] > b->prim)) continue;
            b->t = t;
            b->u = bvh__lane_f(V, i) / d;
            b->v = bvh__lane_f(W, i) / d;
            b->prim = p->prim[i];
            b->pk = p;
            b->lane = i;
            found = 1;
        }
    }
    return found;
}
#ifdef BVH__AVX2
/* bvh__packets on two packets per pass of eight lanes (a leaf's packets are side by side): the
   same operations in the same order on each lane, so the same bits. An odd last packet is loaded
   twice and its copy's lanes are masked off. Not forced inline: only bvh__trace8_avx2, compiled
   for AVX2 as well, takes it in. */
__attribute__((target("avx2"))) static inline __m256 bvh__load8(const float *lo, const float *hi) {
    return _mm256_insertf128_ps(_mm256_castps128_ps256(_mm_loadu_ps(lo)), _mm_loadu_ps(hi), 1);
}
__attribute__((target("avx2"))) static inline float bvh__lane8(__m256 x, unsigned i) {
    float f[8];
    _mm256_storeu_ps(f, x);
    return f[i];
}
/* What the AVX2 packet test reads of the ray, made once a ray (bvh__tri8_setup, after
   bvh__ray_shear): o[kx], o[ky], o[kz], sx, sy, sz and tmin on eight lanes, and the byte offsets
   of axes kx, ky, kz in a row of bvh_tri4.v. The test reads them from here as operands of its
   arithmetic rather than keeping them in registers, which the loop has too few of (set up in
   registers at every leaf, they cost more than the leaf's first pass). */
typedef struct bvh__tri8ray {
    float o[3][8], s[3][8], tmin[8];
    uint32_t row[3];
} bvh__tri8ray;
__attribute__((target("avx2"))) static inline void bvh__tri8_setup(const bvh__rayx *r, bvh__tri8ray *tr) {
    _mm256_storeu_ps(tr->o[0], _mm256_set1_ps(r->o[r->kx]));
    _mm256_storeu_ps(tr->o[1], _mm256_set1_ps(r->o[r->ky]));
    _mm256_storeu_ps(tr->o[2], _mm256_set1_ps(r->o[r->kz]));
    _mm256_storeu_ps(tr->s[0], _mm256_set1_ps(r->sx));
    _mm256_storeu_ps(tr->s[1], _mm256_set1_ps(r->sy));
    _mm256_storeu_ps(tr->s[2], _mm256_set1_ps(r->sz));
    _mm256_storeu_ps(tr->tmin, _mm256_set1_ps(r->tmin));
    tr->row[0] = (uint32_t)r->kx * (uint32_t)sizeof(float[4]);
    tr->row[1] = (uint32_t)r->ky * (uint32_t)sizeof(float[4]);
    tr->row[2] = (uint32_t)r->kz * (uint32_t)sizeof(float[4]);
}
/* Row a (axis kx, ky, kz for a = 0, 1, 2) of vertex k of packets p (lanes 0-3) and p1 (4-7). */
__attribute__((target("avx2"))) BVH__INLINE __m256 bvh__row8(const bvh__tri8ray *tr, const bvh_tri4 *p,
                                                             const bvh_tri4 *p1, int k, int a) {
    return bvh__load8((const float *)(const void *)((const char *)p->v[k] + tr->row[a]),
                      (const float *)(const void *)((const char *)p1->v[k] + tr->row[a]));
}
/* Vertex k of the lanes of packets p (lanes 0-3) and p1 (4-7), translated and sheared. */
__attribute__((target("avx2"))) BVH__INLINE void
bvh__shear8(const bvh__tri8ray *tr, const bvh_tri4 *p, const bvh_tri4 *p1, int k, __m256 *x, __m256 *y, __m256 *z) {
    const __m256 zk = _mm256_sub_ps(bvh__row8(tr, p, p1, k, 2), _mm256_loadu_ps(tr->o[2]));
    *z = zk;
    *x = _mm256_sub_ps(_mm256_sub_ps(bvh__row8(tr, p, p1, k, 0), _mm256_loadu_ps(tr->o[0])),
                       _mm256_mul_ps(_mm256_loadu_ps(tr->s[0]), zk));
    *y = _mm256_sub_ps(_mm256_sub_ps(bvh__row8(tr, p, p1, k, 1), _mm256_loadu_ps(tr->o[1])),
                       _mm256_mul_ps(_mm256_loadu_ps(tr->s[1]), zk));
}
/* bvh__edges_mixed on eight lanes. */
__attribute__((target("avx2"))) BVH__INLINE unsigned bvh__edges_mixed8(__m256 U, __m256 V, __m256 W) {
    const __m256 zero = _mm256_setzero_ps();
    const __m256 neg =
        _mm256_or_ps(_mm256_or_ps(_mm256_cmp_ps(U, zero, _CMP_LT_OQ), _mm256_cmp_ps(V, zero, _CMP_LT_OQ)),
                     _mm256_cmp_ps(W, zero, _CMP_LT_OQ));
    const __m256 pos =
        _mm256_or_ps(_mm256_or_ps(_mm256_cmp_ps(U, zero, _CMP_GT_OQ), _mm256_cmp_ps(V, zero, _CMP_GT_OQ)),
                     _mm256_cmp_ps(W, zero, _CMP_GT_OQ));
    return (unsigned)_mm256_movemask_ps(_mm256_and_ps(neg, pos));
}
__attribute__((target("avx2"))) static inline int
bvh__packets_avx2(const bvh__rayx *r, const bvh__tri8ray *tr, const bvh_tri4 *p, uint32_t np, bvh__best *b, int any) {
    const int kz = r->kz;
    const __m256 zero = _mm256_setzero_ps(), inf = _mm256_set1_ps(BVH_INF);
    uint32_t q;
    int found = 0;
    for (q = 0; q < np; q += 2, p += 2) {
        const uint32_t two = q + 1 < np; /* 0: an odd last packet, its copy's lanes masked off */
        const bvh_tri4 *p1 = p + two;
        /* tr's operands read in each pass, not hoisted out of the loop (into registers that
           would be spilled to other stack slots on every leaf): the compiler cannot see that
           the pointer is the same */
        __asm__("" : "+r"(tr));
        const unsigned lanes = 0x0fu | (0xf0u & (0u - two));
        /* named registers, not arrays: an array indexed in a loop the compiler does not unroll
           lives in memory */
        __m256 x0, y0, z0, x1, y1, z1, x2, y2, z2, U, V, W, ft, det, T, ok, tn, tf, slack;
        unsigned m, zm;
        int a;
        bvh__shear8(tr, p, p1, 0, &x0, &y0, &z0);
        bvh__shear8(tr, p, p1, 1, &x1, &y1, &z1);
        bvh__shear8(tr, p, p1, 2, &x2, &y2, &z2);
        U = _mm256_sub_ps(_mm256_mul_ps(x2, y1), _mm256_mul_ps(y2, x1));
        V = _mm256_sub_ps(_mm256_mul_ps(x0, y2), _mm256_mul_ps(y0, x2));
        W = _mm256_sub_ps(_mm256_mul_ps(x1, y0), _mm256_mul_ps(y1, x0));
        m = lanes & ~bvh__edges_mixed8(U, V, W);
        if (!m) continue;
        zm = m & (unsigned)_mm256_movemask_ps(
                     _mm256_or_ps(_mm256_or_ps(_mm256_cmp_ps(U, zero, _CMP_EQ_OQ), _mm256_cmp_ps(V, zero, _CMP_EQ_OQ)),
                                  _mm256_cmp_ps(W, zero, _CMP_EQ_OQ)));
        if (zm) { /* the lanes left with a zero edge function, redone in double */
            float fx[3][8], fy[3][8], fu[8], fv[8], fw[8];
            _mm256_storeu_ps(fx[0], x0);
            _mm256_storeu_ps(fx[1], x1);
            _mm256_storeu_ps(fx[2], x2);
            _mm256_storeu_ps(fy[0], y0);
            _mm256_storeu_ps(fy[1], y1);
            _mm256_storeu_ps(fy[2], y2);
            _mm256_storeu_ps(fu, U);
            _mm256_storeu_ps(fv, V);
            _mm256_storeu_ps(fw, W);
            bvh__edges_exact_lanes(&fx[0][0], &fy[0][0], fu, fv, fw, zm, 8);
            U = _mm256_loadu_ps(fu);
            V = _mm256_loadu_ps(fv);
            W = _mm256_loadu_ps(fw);
            m &= ~bvh__edges_mixed8(U, V, W);
            if (!m) continue;
        }
        /* bvh__packet_hits on eight lanes */
        det = _mm256_add_ps(_mm256_add_ps(U, V), W);
        T = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(U, _mm256_mul_ps(_mm256_loadu_ps(tr->s[2]), z0)),
                                        _mm256_mul_ps(V, _mm256_mul_ps(_mm256_loadu_ps(tr->s[2]), z1))),
                          _mm256_mul_ps(W, _mm256_mul_ps(_mm256_loadu_ps(tr->s[2]), z2)));
        ft = _mm256_div_ps(T, det);
        ok = _mm256_and_ps(_mm256_cmp_ps(ft, _mm256_loadu_ps(tr->tmin), _CMP_GE_OQ),
                           _mm256_cmp_ps(ft, _mm256_set1_ps(b->t), _CMP_LE_OQ));
        ok = _mm256_and_ps(ok, _mm256_cmp_ps(ft, inf, _CMP_LT_OQ));
        ok = _mm256_and_ps(ok, _mm256_cmp_ps(det, zero, _CMP_NEQ_UQ));
        m &= (unsigned)_mm256_movemask_ps(ok);
        if (!m) continue;
        /* bvh__reach4 on eight lanes: the triangles' boxes (bvh__tri_box) reached by ft */
        /* the axes in the order kx, ky, kz (max and min ignore a NaN first operand, so the order
           does not change the bits), kz's distances last for the slack; the near plane chosen
           by the sign of inv in a blend: branches on a random direction would be random */
        tn = _mm256_set1_ps(r->tmin);
        tf = inf;
        slack = zero;
        for (a = 0; a < 3; a++) {
            const int k = a == 0 ? r->kx : a == 1 ? r->ky : kz;
            const __m256 v0 = bvh__load8(p->v[0][k], p1->v[0][k]), v1 = bvh__load8(p->v[1][k], p1->v[1][k]);
            const __m256 v2 = bvh__load8(p->v[2][k], p1->v[2][k]);
            const __m256 lo = _mm256_min_ps(_mm256_min_ps(v0, v1), v2), hi = _mm256_max_ps(_mm256_max_ps(v0, v1), v2);
            const __m256 o = _mm256_set1_ps(r->o[k]), inv = _mm256_set1_ps(r->inv[k]); /* inv: never -0 */
            const __m256 t0 = _mm256_mul_ps(_mm256_sub_ps(_mm256_blendv_ps(lo, hi, inv), o), inv);
            const __m256 t1 = _mm256_mul_ps(_mm256_sub_ps(_mm256_blendv_ps(hi, lo, inv), o), inv);
            tn = _mm256_max_ps(t0, tn);
            tf = _mm256_min_ps(t1, tf);
            if (a == 2) slack = _mm256_max_ps(t1, _mm256_sub_ps(zero, t0));
        }
        tf = _mm256_mul_ps(tf, _mm256_set1_ps(1.0000004f));
        tn = _mm256_sub_ps(tn, _mm256_mul_ps(slack, _mm256_set1_ps(3.814697265625e-6f)));
        tn = _mm256_max_ps(_mm256_loadu_ps(tr->tmin), tn); /* never below tmin (bvh__slab_t) */
        tf = _mm256_min_ps(tf, ft);
        m &= (unsigned)_mm256_movemask_ps(_mm256_cmp_ps(tn, tf, _CMP_LE_OQ));
        if (!m) continue;
        if (any) {
            const unsigned i = BVH__CTZ(m);
            b->t = bvh__lane8(ft, i);
            b->prim = (i < 4 ? p : p1)->prim[i & 3u];
            b->pk = i < 4 ? p : p1;
            b->lane = i & 3u;
            return 1;
        }
        while (m) { /* the nearest lane; ties in t: the lowest primitive index */
            const unsigned i = BVH__CTZ(m);
            const float t = bvh__lane8(ft, i), d = bvh__lane8(det, i);
            const uint32_t prim = (i < 4 ? p : p1)->prim[i & 3u];
            m &= m - 1;
            if (t > b->t || (t == b->t && prim > b->prim)) continue;
            b->t = t;
            b->u = bvh__lane8(V, i) / d;
            b->v = bvh__lane8(W, i) / d;
            b->prim = prim;
            b->pk = i < 4 ? p : p1;
            b->lane = i & 3u;
            found = 1;
        }
    }
    return found;
}
#define BVH__PACKETS(r, p, np, b, any)                                                                                 \
    (isa ? bvh__packets_avx2(r, &tr8, p, np, b, any) : bvh__packets(r, p, np, b, any))
#endif
#else
static int bvh__packets(const bvh__rayx *r, const bvh_tri4 *p, uint32_t np, bvh__best *b, int any) {
    uint32_t q;
    int i, found = 0;
    for (q = 0; q < np; q++, p++)
        for (i = 0; i < 4; i++) {
            float tri[9], t, u, v;
            bvh__lane(p, i, tri);
            if (!bvh__tri_test(r, tri, b->t, &t, &u, &v)) continue;
            if (t == b->t && p->prim[i] > b->prim) continue;
            b->t = t;
            b->u = u;
            b->v = v;
            b->prim = p->prim[i];
            b->pk = p;
            b->lane = (uint32_t)i;
            found = 1;
            if (any) return 1;
        }
    return found;
}
#endif

#ifdef BVH__SSE
/* The ray as the SIMD slab test wants it in registers, its axes ordered so that the dominant one
   (whose distances set the slack) comes last: max and min do not depend on the order, so the
   same bits as bvh__slab_t. */
typedef struct bvh__ray8 {
    __m128 o[3], inv[3], tmin;
    int near8[4], far8[4];       /* [3]: unused (the AVX2 set-up stores four lanes) */
    float so[4], sinv[4], stmin; /* the same as scalars, for the AVX2 test to broadcast */
    float sinvg[4];              /* sinv * BVH__GROW8 (AVX2 set-up only): the fast test's exits */
    int fast;                    /* tmin >= 0 and no direction component zero: bvh__slab8_avx2's integer max and min */
} bvh__ray8;
/* bvh__ray_setup for the wide traversal, and the ray as the slab tests want it: the same bits (SSE
   rounds 1 / d as scalar code does), the three axes at once. Only what the SIMD wide traversal
   reads: not the plain-C slab test's plane offsets (near, near8, far8), and the SSE registers
   only when the slab test is the SSE one (sse). */
/* kz (the dominant axis, first of equals in the order z, y, x as bvh__ray_setup picks it) from
   the three comparisons |dx| > |dy|, |dx| > |dz|, |dy| > |dz| as bits 0-2, looked up rather than
   branched on: a diffuse ray's direction is random, and so would the branches be. */
static const unsigned char bvh__kz[8] = {2, 2, 2, 0, 1, 2, 1, 0};
/* The slab tests' axes: the two after kz in cyclic order, then kz (last: its distances give the
   slack). Which of the other two comes first changes no bit (see bvh__slab8_avx2), so the set-up
   need not know kx and ky, which bvh__ray_shear makes at the first leaf. */
static const int32_t bvh__slab_axes[3][4] = {{1, 2, 0, 0}, {2, 0, 1, 0}, {0, 1, 2, 0}};
/* [kz][neg]: near8[0..2], 0, far8[0..2], 0 of the slab axes (the float offsets in a bvh_node8
   of slot 0's near and far planes), where bit k of neg says inv[k] < 0: for axis
   k = bvh__slab_axes[kz][s] and n = bit k, near8[s] = 8k + 24n and far8[s] = 8k + 24 - 24n. */
static const unsigned char bvh__slab_planes[3][8][8] = {{{8, 16, 0, 0, 32, 40, 24, 0},
                                                         {8, 16, 24, 0, 32, 40, 0, 0},
                                                         {32, 16, 0, 0, 8, 40, 24, 0},
                                                         {32, 16, 24, 0, 8, 40, 0, 0},
                                                         {8, 40, 0, 0, 32, 16, 24, 0},
                                                         {8, 40, 24, 0, 32, 16, 0, 0},
                                                         {32, 40, 0, 0, 8, 16, 24, 0},
                                                         {32, 40, 24, 0, 8, 16, 0, 0}},
                                                        {{16, 0, 8, 0, 40, 24, 32, 0},
                                                         {16, 24, 8, 0, 40, 0, 32, 0},
                                                         {16, 0, 32, 0, 40, 24, 8, 0},
                                                         {16, 24, 32, 0, 40, 0, 8, 0},
                                                         {40, 0, 8, 0, 16, 24, 32, 0},
                                                         {40, 24, 8, 0, 16, 0, 32, 0},
                                                         {40, 0, 32, 0, 16, 24, 8, 0},
                                                         {40, 24, 32, 0, 16, 0, 8, 0}},
                                                        {{0, 8, 16, 0, 24, 32, 40, 0},
                                                         {24, 8, 16, 0, 0, 32, 40, 0},
                                                         {0, 32, 16, 0, 24, 8, 40, 0},
                                                         {24, 32, 16, 0, 0, 8, 40, 0},
                                                         {0, 8, 40, 0, 24, 32, 16, 0},
                                                         {24, 8, 40, 0, 0, 32, 16, 0},
                                                         {0, 32, 40, 0, 24, 8, 16, 0},
                                                         {24, 32, 40, 0, 0, 8, 16, 0}}};
/* The fast slab test's factor on the exits (see bvh__trace8_reach): 1 + 6 * 2^-23. */
#define BVH__GROW8 1.00000072f
#ifdef BVH__AVX2
/* The slab tests' operands: o and -inv permuted to bvh__slab_axes[kz] (AVX2's variable permute;
   (o - b) * -inv is (b - o) * inv, bit for bit but for the sign of a zero, and lets the slab test
   read b by the subtraction itself) and the plane offsets from bvh__slab_planes. */
__attribute__((target("avx2"))) static inline void bvh__ray8_axes_avx2(bvh__ray8 *q, const bvh__rayx *rx, __m128 o,
                                                                       __m128 inv, unsigned neg) {
    const __m128i k = _mm_loadu_si128((const __m128i *)(const void *)bvh__slab_axes[rx->kz]);
    const unsigned char *pl = bvh__slab_planes[rx->kz][neg & 7u];
    int32_t nf[2];
    memcpy(nf, pl, sizeof nf);
    _mm_storeu_ps(q->so, _mm_permutevar_ps(o, k));
    const __m128 sinv = _mm_permutevar_ps(_mm_xor_ps(inv, _mm_set1_ps(-0.0f)), k); /* -inv, bit for bit */
    _mm_storeu_ps(q->sinv, sinv);
    _mm_storeu_ps(q->sinvg, _mm_mul_ps(sinv, _mm_set1_ps(BVH__GROW8)));
    _mm_storeu_si128((__m128i *)(void *)q->near8, _mm_cvtepu8_epi32(_mm_cvtsi32_si128(nf[0])));
    _mm_storeu_si128((__m128i *)(void *)q->far8, _mm_cvtepu8_epi32(_mm_cvtsi32_si128(nf[1])));
}
#endif
BVH__INLINE int bvh__ray8_start(const bvh_ray *ray, bvh__rayx *rx, bvh__ray8 *q, int sse) {
    const __m128 o = _mm_loadu_ps(&ray->origin.x), d0 = _mm_loadu_ps(&ray->dir.x); /* xyz, tmin / tmax */
    const __m128 absm = _mm_castsi128_ps(_mm_set1_epi32(0x7fffffff)), inf = _mm_set1_ps(BVH_INF);
    const __m128 zero = _mm_setzero_ps(), ad0 = _mm_and_ps(d0, absm);
    /* a subnormal component counts as +0, as in bvh__ray_setup */
    const __m128 d = _mm_andnot_ps(_mm_cmplt_ps(ad0, _mm_set1_ps(FLT_MIN)), d0), ad = _mm_and_ps(d, absm);
    const __m128 inv = _mm_div_ps(_mm_set1_ps(1.0f), d); /* 1 / +0 = +inf */
    const unsigned finite =
        (unsigned)_mm_movemask_ps(_mm_and_ps(_mm_cmplt_ps(_mm_and_ps(o, absm), inf), _mm_cmplt_ps(ad0, inf)));
    const unsigned neg = (unsigned)_mm_movemask_ps(_mm_cmplt_ps(inv, zero));
    const unsigned dzero = (unsigned)_mm_movemask_ps(_mm_cmpeq_ps(d, zero)) & 7u; /* x, y, z: zero components */
    /* |dx| > |dy|, |dx| > |dz|, |dy| > |dz| as bits 0-2 */
    const unsigned gt = (unsigned)_mm_movemask_ps(
        _mm_cmpgt_ps(_mm_shuffle_ps(ad, ad, _MM_SHUFFLE(3, 1, 0, 0)), _mm_shuffle_ps(ad, ad, _MM_SHUFFLE(3, 2, 2, 1))));
    char *x = (char *)(void *)rx;
    int a;
    /* !(tmin <= tmax): also a NaN in either */
    if ((finite & 7u) != 7u || !(ray->tmin <= ray->tmax)) return 0;
    if (dzero == 7u) return 0;
    q->fast = ray->tmin >= 0.0f && !dzero;
    /* o, d, inv and tmin are side by side in bvh__rayx: three stores of four lanes into its
       bytes, each fourth lane overwritten by the next store, the last by tmin */
    _mm_storeu_ps((float *)(void *)(x + offsetof(bvh__rayx, o)), o);
    _mm_storeu_ps((float *)(void *)(x + offsetof(bvh__rayx, d)), d);
    _mm_storeu_ps((float *)(void *)(x + offsetof(bvh__rayx, inv)), inv);
    rx->tmin = ray->tmin;
    rx->kz = bvh__kz[gt & 7u];
#ifdef BVH__AVX2
    if (!sse) /* the AVX2 loop's set-up */
        bvh__ray8_axes_avx2(q, rx, o, inv, neg);
    else
#endif
    {
        const int32_t *k = bvh__slab_axes[rx->kz];
        const unsigned char *pl = bvh__slab_planes[rx->kz][neg & 7u];
        for (a = 0; a < 3; a++) { /* bvh__ray8_axes_avx2, one axis at a time */
            q->so[a] = rx->o[k[a]];
            q->sinv[a] = -rx->inv[k[a]];
            q->near8[a] = pl[a];
            q->far8[a] = pl[4 + a];
        }
    }
    q->stmin = rx->tmin + 0.0f; /* -0 as +0: the same decisions, and the integer max's order */
    if (sse) {
        for (a = 0; a < 3; a++) {
            q->o[a] = _mm_set1_ps(q->so[a]);
            q->inv[a] = _mm_set1_ps(q->sinv[a]);
        }
        q->tmin = _mm_set1_ps(rx->tmin);
    }
    return 1;
}
/* bvh__slab_t on the four slots of a node whose box arrays start at f (slot 0 or 4); bit i of the
   result: slot i entered before tfar, *tn their entry distances. */
BVH__INLINE unsigned bvh__slab4q(const bvh__ray8 *q, const float *f, __m128 tfar, __m128 *tn_out) {
    const __m128 t0a = _mm_mul_ps(_mm_sub_ps(q->o[0], _mm_loadu_ps(f + q->near8[0])), q->inv[0]);
    const __m128 t1a = _mm_mul_ps(_mm_sub_ps(q->o[0], _mm_loadu_ps(f + q->far8[0])), q->inv[0]);
    const __m128 t0b = _mm_mul_ps(_mm_sub_ps(q->o[1], _mm_loadu_ps(f + q->near8[1])), q->inv[1]);
    const __m128 t1b = _mm_mul_ps(_mm_sub_ps(q->o[1], _mm_loadu_ps(f + q->far8[1])), q->inv[1]);
    const __m128 t0c = _mm_mul_ps(_mm_sub_ps(q->o[2], _mm_loadu_ps(f + q->near8[2])), q->inv[2]);
    const __m128 t1c = _mm_mul_ps(_mm_sub_ps(q->o[2], _mm_loadu_ps(f + q->far8[2])), q->inv[2]);
    const __m128 grow = _mm_set1_ps(1.0000004f), k = _mm_set1_ps(3.814697265625e-6f); /* 2^-18 */
    /* _mm_max_ps(a, b) is a > b ? a : b and _mm_min_ps(a, b) is a < b ? a : b: a NaN first gives
       the second. bvh__slab_t's operations regrouped into trees for a short chain from the boxes
       to the mask; the same bits but for the sign of a zero (see bvh__slab8_avx2). */
    const __m128 tn = _mm_max_ps(
        q->tmin, _mm_sub_ps(_mm_max_ps(_mm_max_ps(t0a, t0c), _mm_max_ps(t0b, q->tmin)),
                            _mm_max_ps(_mm_mul_ps(t1c, k), _mm_mul_ps(t0c, _mm_set1_ps(-3.814697265625e-6f)))));
    const __m128 tf = _mm_min_ps(_mm_mul_ps(_mm_min_ps(t1a, t1c), grow), _mm_min_ps(_mm_mul_ps(t1b, grow), tfar));
    *tn_out = tn;
    /* entered: tn <= tf, where tf <= tfar is finite (bvh__slab8q clamps it to FLT_MAX), so tn is
       too, as bvh__slab_t wants (a ray parallel to an axis outside the slab gets tn = +inf) */
    return (unsigned)_mm_movemask_ps(_mm_cmple_ps(tn, tf));
}
BVH__INLINE unsigned bvh__slab8q(const bvh__ray8 *q, const bvh_node8 *n, float tfar, float tn_out[BVH__W]) {
    const __m128 tf = _mm_set1_ps(tfar < FLT_MAX ? tfar : FLT_MAX);
    __m128 lo, hi;
    unsigned m = bvh__slab4q(q, &n->min[0][0], tf, &lo) | bvh__slab4q(q, &n->min[0][4], tf, &hi) << 4;
    _mm_storeu_ps(tn_out, lo);
    _mm_storeu_ps(tn_out + 4, hi);
    return m;
}
#ifdef BVH__AVX2
/* bvh__slab8q in one pass of eight lanes: the same decisions, with the operations regrouped so
   that the chain from a node's boxes to the next node's address is short (a ray that descends
   waits for it at every level). Every regrouping gives the same bits but for the sign of a zero:
   max and min of the three axes as a tree, a NaN (the origin on an axis-parallel ray's plane; only
   axes a and b, kz's distances are never NaN) always first against a number; the factors
   1.0000004 and 2^-18 applied before the min and max they commute with (x * c is monotone for
   c > 0, and x * 2^-18 is exact but below 2^-108, where the slack does not matter). With fast
   (rays with tmin >= 0 and no zero direction component, chosen once a ray), a looser test whose
   slack and exit factor are off that chain: see bvh__trace8_reach; fast 1 takes the max and min
   over the axes as integer operations, fast 2 (AMD's cores) as float ones. Not forced inline: only
   bvh__traverse8_avx2, compiled for AVX2 as well, takes it in. */
/* Max and min of floats by their bits as signed integers (see bvh__slab8_avx2). */
__attribute__((target("avx2"))) BVH__INLINE __m256 bvh__imax8(__m256 a, __m256 b) {
    return _mm256_castsi256_ps(_mm256_max_epi32(_mm256_castps_si256(a), _mm256_castps_si256(b)));
}
__attribute__((target("avx2"))) BVH__INLINE __m256 bvh__imin8(__m256 a, __m256 b) {
    return _mm256_castsi256_ps(_mm256_min_epi32(_mm256_castps_si256(a), _mm256_castps_si256(b)));
}
__attribute__((target("avx2,fma"))) static inline unsigned
bvh__slab8_avx2(const bvh__ray8 *q, const bvh_node8 *n, float tfar, float tn_out[BVH__W], int fast, float reach) {
    const float *f = &n->min[0][0];
    const __m256 oa = _mm256_broadcast_ss(&q->so[0]), ob = _mm256_broadcast_ss(&q->so[1]);
    const __m256 oc = _mm256_broadcast_ss(&q->so[2]), ia = _mm256_broadcast_ss(&q->sinv[0]);
    const __m256 ib = _mm256_broadcast_ss(&q->sinv[1]), ic = _mm256_broadcast_ss(&q->sinv[2]);
    const __m256 tfar8 = _mm256_set1_ps(tfar < FLT_MAX ? tfar : FLT_MAX);
    __m256 t0a, t1a, t0b, t1b, t0c, t1c, tn, slack, tns, tf;
    if (fast) { /* a constant: q->fast, chosen once a ray (bvh__trace8) */
        /* A looser test than the one below, never a tighter one: every box that one enters this
           one enters too, at the same distance or a nearer one (bvh__trace8_reach says why), so
           the hits stay the brute force's. The slack is reach, one per ray and tree, taken off
           each entry in the multiply that makes it (one rounding, fused); the exits are widened
           by the factor in sinvg. Neither is then on the chain from the boxes to the mask. */
        const __m256 r = _mm256_set1_ps(reach), stmin = _mm256_broadcast_ss(&q->stmin);
        t0a = _mm256_fmsub_ps(_mm256_sub_ps(oa, _mm256_loadu_ps(f + q->near8[0])), ia, r);
        t0b = _mm256_fmsub_ps(_mm256_sub_ps(ob, _mm256_loadu_ps(f + q->near8[1])), ib, r);
        t0c = _mm256_fmsub_ps(_mm256_sub_ps(oc, _mm256_loadu_ps(f + q->near8[2])), ic, r);
        t1a = _mm256_mul_ps(_mm256_sub_ps(oa, _mm256_loadu_ps(f + q->far8[0])), _mm256_broadcast_ss(&q->sinvg[0]));
        t1b = _mm256_mul_ps(_mm256_sub_ps(ob, _mm256_loadu_ps(f + q->far8[1])), _mm256_broadcast_ss(&q->sinvg[1]));
        t1c = _mm256_mul_ps(_mm256_sub_ps(oc, _mm256_loadu_ps(f + q->far8[2])), _mm256_broadcast_ss(&q->sinvg[2]));
        /* fast 1: the max and min by integer max and min (on Intel's cores one cycle each, four
           for the float ones, on the chain to the mask), where they give the same values or
           looser ones. Here no distance is NaN (every inv is finite, and so is reach) and
           tmin >= +0. A float's bits as a
           signed integer order non-negative floats as the floats and put every negative one
           below them. Among negative floats the order is reversed. So the max over the t0 is
           the float max where one of them is >= 0, and some negative value where none is, which
           the max with tmin turns into tmin as it does the float max (tmin is a fourth operand
           of the tree: no deeper, and one compare, tn <= tf, decides). The min over the t1 is
           the float min or a larger value (when two or more are negative): a box is never culled
           that the float min would let in, and the entry distances are the float max's. */
        if (fast == 2) { /* AMD: float max and min take one cycle there, as the integer ones do,
                            and these stay off the integer unit (a cycle's crossing each way) */
            tns = _mm256_max_ps(_mm256_max_ps(t0a, t0c), _mm256_max_ps(t0b, stmin));
            tf = _mm256_min_ps(_mm256_min_ps(t1a, t1c), _mm256_min_ps(t1b, tfar8));
        } else {
            tns = bvh__imax8(bvh__imax8(t0a, t0c), bvh__imax8(t0b, stmin));
            tf = bvh__imin8(bvh__imin8(t1a, t1c), bvh__imin8(t1b, tfar8));
        }
        _mm256_storeu_ps(tn_out, tns);
        return (unsigned)_mm256_movemask_ps(_mm256_cmp_ps(tns, tf, _CMP_LE_OQ));
    }
    t0a = _mm256_mul_ps(_mm256_sub_ps(oa, _mm256_loadu_ps(f + q->near8[0])), ia);
    t1a = _mm256_mul_ps(_mm256_sub_ps(oa, _mm256_loadu_ps(f + q->far8[0])), ia);
    t0b = _mm256_mul_ps(_mm256_sub_ps(ob, _mm256_loadu_ps(f + q->near8[1])), ib);
    t1b = _mm256_mul_ps(_mm256_sub_ps(ob, _mm256_loadu_ps(f + q->far8[1])), ib);
    t0c = _mm256_mul_ps(_mm256_sub_ps(oc, _mm256_loadu_ps(f + q->near8[2])), ic);
    t1c = _mm256_mul_ps(_mm256_sub_ps(oc, _mm256_loadu_ps(f + q->far8[2])), ic);
    /* tn = max(tmin, t0a, t0b, t0c), less the slack max(t1c, -t0c) * 2^-18 */
    tn = _mm256_max_ps(_mm256_max_ps(t0a, t0c), _mm256_max_ps(t0b, _mm256_broadcast_ss(&q->stmin)));
    slack = _mm256_max_ps(_mm256_mul_ps(t1c, _mm256_set1_ps(3.814697265625e-6f)), /* 2^-18 */
                          _mm256_mul_ps(t0c, _mm256_set1_ps(-3.814697265625e-6f)));
    tns = _mm256_max_ps(_mm256_broadcast_ss(&q->stmin), _mm256_sub_ps(tn, slack));
    /* tf = min(t1a, t1b, t1c) * 1.0000004, at most tfar and at most FLT_MAX: then tn <= tf says tn
       is finite too (one compare) */
    {
        const __m256 grow = _mm256_set1_ps(1.0000004f);
        tf =
            _mm256_min_ps(_mm256_mul_ps(_mm256_min_ps(t1a, t1c), grow), _mm256_min_ps(_mm256_mul_ps(t1b, grow), tfar8));
    }
    _mm256_storeu_ps(tn_out, tns);
    return (unsigned)_mm256_movemask_ps(_mm256_cmp_ps(tns, tf, _CMP_LE_OQ));
}
#define BVH__SLAB8(n, tfar, tn)                                                                                        \
    (isa ? bvh__slab8_avx2(q, n, tfar, tn, isa >= 2 ? isa - 1 : 0, reach) : bvh__slab8q(q, n, tfar, tn))
/* The slots of mask m (three or more) nearest first into idx, by rank rather than by insertion:
   slot i's place is the number of slots of m whose key is below its own, counted from one compare
   of all eight keys at once. A key is the distance's bits with the slot number in the lowest
   three: unique, and in the order of the distances where they are not negative (a box the ray
   starts in has a distance just below tmin; their order among themselves, reversed, only changes
   which is visited first). No loop that depends on the distances, so no branch to mispredict but
   the one over m. Returns the count. */
__attribute__((target("avx2,popcnt"))) static inline uint32_t bvh__order8_avx2(const float tn[BVH__W], unsigned m,
                                                                               uint32_t idx[BVH__W]) {
    const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    const __m256i key =
        _mm256_or_si256(_mm256_andnot_si256(_mm256_set1_epi32(7), _mm256_castps_si256(_mm256_loadu_ps(tn))), lane);
    unsigned r = m;
    while (r) {
        const unsigned i = BVH__CTZ(r);
        const __m256i ki = _mm256_permutevar8x32_epi32(key, _mm256_set1_epi32((int)i));
        r &= r - 1;
        idx[_mm_popcnt_u32(m & (unsigned)_mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(ki, key))))] = i;
    }
    return (uint32_t)_mm_popcnt_u32(m);
}
#else
#define BVH__SLAB8(n, tfar, tn) bvh__slab8q(q, n, tfar, tn)
#endif
#else
#define BVH__SLAB8(n, tfar, tn) bvh__slab8(rx, n, tfar, tn)
typedef struct bvh__ray8 {
    int unused;
} bvh__ray8; /* plain C: the slab test reads bvh__rayx */
#endif
#ifndef BVH__PACKETS
#define BVH__PACKETS(r, p, np, b, any) bvh__packets(r, p, np, b, any)
#endif
/* Slot i of node n onto the stack. Its lines are asked for now, so that they arrive while the
   nearer children are being tested (the nearest child is read at once: asking for it gains
   nothing). Any hit (a constant where inlined) leaves the entry distance out: its loop ends at
   the first hit, so tmax never falls below a distance pushed before it. */
BVH__INLINE void bvh__push8(const bvh_node8 *nodes, const bvh_tri4 *tri4, const bvh_node8 *n, unsigned i,
                            const float *tn, bvh__entry8 *stack, uint32_t *sp, int packets, int any) {
    const uint32_t c = n->child[i], k = n->count[i];
    if (packets) { /* a constant where inlined; 0: leaves of instances, whose lines are elsewhere */
        /* leaves and nodes alternate at random, so the address is a select, not a branch; for
           closest hit by masks that the compiler cannot turn back into a branch (gcc made one of
           the plain ?:, a misprediction a ray or more on long rays: docs/bench 0.9.21). Any hit
           keeps the ?:, the faster of the two there. */
        const char *a;
        if (!any) {
            uintptr_t leaf = (uintptr_t)0 - (uintptr_t)(k != 0);
            BVH__OPAQUE(leaf);
            a = (const char *)(((uintptr_t)(nodes + c) & ~leaf) | ((uintptr_t)(tri4 + c) & leaf));
        } else
            a = k ? (const char *)(tri4 + c) : (const char *)(nodes + c);
        BVH__PREFETCH(a);
        BVH__PREFETCH(a + 64);
        BVH__PREFETCH(a + 128);
    } else if (!k) {
        BVH__PREFETCH(nodes + c);
        BVH__PREFETCH((const char *)(nodes + c) + 64);
        BVH__PREFETCH((const char *)(nodes + c) + 128);
    }
    stack[*sp].child = c;
    stack[*sp].count = k;
    if (!any) stack[*sp].t = tn[i];
    ++*sp;
}
/* A leaf step of the 8-wide loop for leaves that are not triangle packets (a scene's top level:
   one instance a leaf slot): tests item `item` (the slot's child; count, the slot's count, says
   what kind of item) with the world ray, whose tmax is the best t so far, set up as rx and q;
   returns 1 when it took a hit as the new best and lowered ray->tmax to its t. isa as
   bvh__traverse8_body's. */
typedef int (*bvh__slot_step)(void *ctx, bvh_ray *ray, bvh__rayx *rx, const bvh__ray8 *q, uint32_t item, uint32_t count,
                              int isa);
/* One loop for closest and any hit: a node's entered children nearest first (any hit: in slot
   order, unsorted), the farther ones on the stack; a leaf's packets tested at once, or, with a
   step (and tri4 NULL), each leaf slot handed to it with the world ray wray. isa (a constant:
   the loop is compiled once for each): 0 SSE or plain C, 1 AVX2 (the slab test in one pass, the
   leaf test on eight lanes), 2 and 3 AVX2 with the fast slab test (its integer, its float max
   and min). */
BVH__INLINE int bvh__traverse8_body(const bvh_node8 *nodes, const bvh_tri4 *tri4, bvh__rayx *rx, const bvh__ray8 *q,
                                    float reach, float tmax, bvh_hit *hit, bvh__best *loc, int any, int isa,
                                    bvh__slot_step step, void *ctx, bvh_ray *wray) {
    bvh__entry8 stack[(BVH__W - 1) * BVH_MAX_DEPTH + 8];
    uint32_t sp = 0, cur = 0, lc = 0; /* lc > 0: cur is a leaf's first packet */
    bvh__best best;
    int sheared = 0;
    float tbest = tmax; /* best.t, kept in a register: best itself lives in memory for the leaf test */
#ifdef BVH__AVX2
    bvh__tri8ray tr8; /* made at the first leaf */
#endif
    best.t = tmax;
    best.u = best.v = 0.0f;
    best.prim = BVH_INVALID;
    best.pk = NULL;
    best.lane = 0;
    (void)q;
    (void)reach;
    for (;;) {
        if (!lc) { /* an interior node: test its children */
            const bvh_node8 *n = &nodes[cur];
            float tn[BVH__W];
            unsigned m, i0, i1;
            /* the children's line, asked for now: it is read only once the boxes are tested */
            BVH__PREFETCH(n->child);
            m = BVH__SLAB8(n, tbest, tn);
            if (step && m == 1u) {
                /* a scene's top level, only slot 0 entered (a one-instance scene's every ray that
                   reaches its instance; slot 0 is the largest box): the slot's item read without
                   waiting for the mask's index, so the instance's own set-up and root do not
                   queue behind this node's test (the branch is predicted, the index would not be) */
                cur = n->child[0];
                lc = n->count[0];
                continue;
            }
            if (m) {
                i0 = BVH__CTZ(m);
                m &= m - 1;
                if (!m) { /* one child: no stack */
                    cur = n->child[i0];
                    lc = n->count[i0];
                    continue;
                }
                if (sp + BVH__W > sizeof stack / sizeof stack[0]) goto out; /* deeper than builders make */
                i1 = BVH__CTZ(m);
                m &= m - 1;
                if (!any && !m) { /* two: the farther one waits */
                    if (tn[i1] < tn[i0]) {
                        unsigned x = i0;
                        i0 = i1;
                        i1 = x;
                    }
                    bvh__push8(nodes, tri4, n, i1, tn, stack, &sp, !step, any);
                } else if (any) { /* any hit: in slot order (leaf slots first), the last pushed first */
                    m |= 1u << i1;
                    while (m) {
                        i1 = BVH__TOP_BIT(m);
                        m &= ~(1u << i1);
                        bvh__push8(nodes, tri4, n, i1, tn, stack, &sp, !step, any);
                    }
                } else { /* three or more: nearest first (AVX2: by rank; else by insertion) */
                    uint32_t idx[BVH__W], k = 2, j;
#ifdef BVH__AVX2
                    if (isa)
                        k = bvh__order8_avx2(tn, m | 1u << i0 | 1u << i1, idx);
                    else
#endif
                    {
                        idx[0] = tn[i1] < tn[i0] ? i1 : i0;
                        idx[1] = tn[i1] < tn[i0] ? i0 : i1;
                        while (m) {
                            unsigned i = BVH__CTZ(m);
                            m &= m - 1;
                            for (j = k; j > 0 && tn[idx[j - 1]] > tn[i]; j--) idx[j] = idx[j - 1];
                            idx[j] = i;
                            k++;
                        }
                    }
                    for (j = k - 1; j > 0; j--) /* farthest at the bottom */
                        bvh__push8(nodes, tri4, n, idx[j], tn, stack, &sp, !step, any);
                    i0 = idx[0];
                }
                cur = n->child[i0];
                lc = n->count[i0];
                continue;
            }
        } else if (step) { /* a leaf slot: its item */
            if (step(ctx, wray, rx, q, cur, lc, isa)) {
                best.prim = cur;
                best.t = tbest = wray->tmax;
                if (any) goto out;
            }
        } else { /* a leaf: its packets */
            if (!sheared) {
                bvh__ray_shear(rx);
#ifdef BVH__AVX2
                if (isa) bvh__tri8_setup(rx, &tr8);
#endif
                sheared = 1;
            }
            if (BVH__PACKETS(rx, tri4 + cur, lc, &best, any)) {
                if (any) goto out;
                tbest = best.t;
            }
        }
        for (;;) { /* pop the next node still in reach of the current best */
            if (!sp) goto out;
            --sp;
            if (any || stack[sp].t <= tbest) { /* any hit: always (bvh__push8) */
                cur = stack[sp].child;
                lc = stack[sp].count;
                break;
            }
        }
    }
out:
    (void)isa;
    if (best.prim == BVH_INVALID) return 0;
    if (hit) {
        hit->t = best.t;
        hit->u = best.u;
        hit->v = best.v;
        hit->prim = best.prim;
    }
    if (loc) *loc = best;
    return 1;
}
/* The ray's set-up for the wide loop (0: a ray no box can take, see bvh__ray_setup). */
BVH__INLINE int bvh__ray8_setup(const bvh_ray *ray, bvh__rayx *rx, bvh__ray8 *q, int isa) {
#ifdef BVH__SSE
    return bvh__ray8_start(ray, rx, q, !isa);
#else
    (void)q;
    (void)isa;
    return bvh__ray_setup(ray, rx);
#endif
}
#ifdef BVH__AVX2
/* The slack of the fast slab test (bvh__slab8_avx2) for a ray and a tree: 1.25 * 2^-18 of the
   largest distance along the dominant axis kz from the origin to a plane of the tree's root box,
   plus FLT_MIN. Why that test is then looser than the exact one: a box inside the root has its kz
   planes between the root's, so the exact test's slack for it, 2^-18 max(t1c, -t0c), is at most
   2^-18 of that distance; the extra quarter covers this product's roundings and half an ulp of
   the box's entry distance (for a box the exact test enters, no more than that distance), and
   FLT_MIN the subnormal ones. So each entry, (o - b) * -inv - reach rounded once, is at most the
   exact test's tn - slack rounded, and each exit, (o - b) * (-inv * BVH__GROW8), at least its
   rounded (o - b) * -inv * 1.0000004 (BVH__GROW8 exceeds 1.0000004 by two ulps and a spare one:
   the two extra roundings either way). Every box the exact test enters, this one enters, at the
   same or a nearer distance. An overflow gives FLT_MAX, not +inf: an entry that overflowed less an
   infinite slack would be NaN, which enters no box. */
BVH__INLINE float bvh__trace8_reach(const bvh_tree *tree, const bvh__rayx *rx) {
    const int kz = rx->kz;
    const float o = rx->o[kz], lo = (&tree->nodes[0].min.x)[kz], hi = (&tree->nodes[0].max.x)[kz];
    const float a = fabsf(lo - o), b = fabsf(hi - o);
    const float r = (a > b ? a : b) * fabsf(rx->inv[kz]) * 4.76837158203125e-6f + FLT_MIN; /* 1.25 * 2^-18 */
    return r < FLT_MAX ? r : FLT_MAX;
}
#endif
/* The ray's set-up and the loop in one function for each ISA and kind, so that a ray that misses
   after a node or two pays one call, and its set-up is not passed on through memory; or, with
   ray NULL, the loop on a ray already set up for this ISA (rx, q, tmax: a scene's world ray for
   an instance placed by the identity; rx gets the shear). hit, when given, gets the miss record
   (t = tmax, prim BVH_INVALID) where no triangle is hit, as bvh__traverse; loc, when given, the
   hit's packet and lane too (untouched on a miss). */
BVH__INLINE int bvh__trace8(const bvh_tree *tree, const bvh_ray *ray, bvh__rayx *rx, const bvh__ray8 *q, float tmax,
                            bvh_hit *hit, bvh__best *loc, int any, int isa) {
    bvh__rayx own;
    bvh__ray8 oq;
    if (ray) {
        tmax = ray->tmax;
        rx = &own;
        q = &oq;
        if (!bvh__ray8_setup(ray, &own, &oq, isa)) goto miss;
    }
#ifdef BVH__AVX2
    if (isa && q->fast) { /* the loop with the fast slab test, chosen once a ray: isa 2, or 3 on AMD */
        const float reach = bvh__trace8_reach(tree, rx);
        if (bvh__slab_float()
                ? bvh__traverse8_body(tree->nodes8, tree->tri4, rx, q, reach, tmax, hit, loc, any, 3, NULL, NULL, NULL)
                : bvh__traverse8_body(tree->nodes8, tree->tri4, rx, q, reach, tmax, hit, loc, any, 2, NULL, NULL, NULL))
            return 1;
        goto miss;
    }
#endif
    if (bvh__traverse8_body(tree->nodes8, tree->tri4, rx, q, 0.0f, tmax, hit, loc, any, isa, NULL, NULL, NULL))
        return 1;
miss:
    if (hit) {
        hit->t = tmax;
        hit->u = hit->v = 0.0f;
        hit->prim = BVH_INVALID;
    }
    return 0;
}
#ifdef BVH__AVX2
__attribute__((target("avx2,fma,popcnt"), flatten)) static int bvh__closest8_avx2(const bvh_tree *tree,
                                                                                  const bvh_ray *ray, bvh__rayx *rx,
                                                                                  const bvh__ray8 *q, float tmax,
                                                                                  bvh_hit *hit, bvh__best *loc) {
    return bvh__trace8(tree, ray, rx, q, tmax, hit, loc, 0, 1);
}
__attribute__((target("avx2,fma,popcnt"), flatten)) static int
bvh__any8_avx2(const bvh_tree *tree, const bvh_ray *ray, bvh__rayx *rx, const bvh__ray8 *q, float tmax) {
    return bvh__trace8(tree, ray, rx, q, tmax, NULL, NULL, 1, 1);
}
/* == two rays in turns ==
   A ray that descends a tree much larger than the caches waits at every level for its node's
   lines; the core cannot start the next ray's loads meanwhile, as a mispredicted branch of this
   one flushes whatever it ran ahead. A batch's rays are therefore taken two at a
   time where that pays (bvh__pair_wanted): a step of one (a node or a leaf, then the next entry
   from its stack) and a step of the other in turns, each ray's loop state in registers, the rest
   of it (set-up, stack, best hit) in a bvh__pair_ray. Each ray takes exactly the steps of
   bvh__traverse8_body with the fast slab test, so the hits are the same bytes; any-hit rays
   likewise. The rays the fast test does not take (tmin < 0, a zero direction component) go
   through bvh__trace8 alone. */
#ifndef BVH__PAIR /* private; the tests set 1 (always in turns) or 0 (never) */
#define BVH__PAIR (-1)
#endif
/* The 8-wide layout's sizes from which rays go in turns. Any hit: shadow rays gained 1-33% on
   every tree from 0.9 MB up (and 7-16% on the large ones), and lost on a tiny one. Closest hit:
   from BVH__PAIR_BYTES, far past a core's L2 (1-2 MiB), bounce rays traced 11-19% faster (the
   dragon, gen:field:15); between the two sizes it depends on the rays: 9-11% faster on an
   object's bounce rays (the bunny), 3-5% slower on a room's (Sponza from inside), so there a
   thread times both ways on the batch's own rays (bvh__pair_tune). Below BVH__PAIR_ANY_BYTES,
   one ray at a time (docs/bench, 0.9.20 and 0.9.21). */
#define BVH__PAIR_BYTES ((size_t)16 << 20)
#define BVH__PAIR_ANY_BYTES ((size_t)512 << 10)
typedef struct bvh__pair_ray {
    bvh__rayx rx;
    bvh__ray8 q;
    bvh__tri8ray tr8;
    bvh__best best;
    float reach;
    int sheared;
    size_t idx;
    bvh__entry8 stack[(BVH__W - 1) * BVH_MAX_DEPTH + 8];
} bvh__pair_ray;
/* 1 to take rays i..e in turns (any: any-hit rays), 2 where timing both ways should decide, 0 for
   one at a time: two or more rays and a layout of the kind's size; then rays from different
   origins (a renderer's bounces and shadow rays) in turns from BVH__PAIR_BYTES, timed between the
   sizes; a camera's closest-hit rays, which share their origin, timed at every size: seen from
   outside, most stop after a node or two and ran 13-20% slower in turns (a ray's state in
   memory), seen from inside a model or a room every one goes deep and ran up to 1.37x as fast
   (docs/bench, 0.9.25). */
static int bvh__pair_wanted(const bvh_tree *t, const bvh_ray *rays, size_t i, size_t e, int any) {
    const size_t bytes = (size_t)t->node8_count * sizeof(bvh_node8) + (size_t)t->tri4_count * sizeof(bvh_tri4);
    if (BVH__PAIR >= 0) return BVH__PAIR && e - i >= 2;
    if (e - i < 2 || bytes < BVH__PAIR_ANY_BYTES) return 0;
    if (!memcmp(&rays[i].origin, &rays[i + 1].origin, sizeof(bvh_vec3))) return any ? 0 : 2;
    return any || bytes >= BVH__PAIR_BYTES ? 1 : 2;
}
/* A ray the fast slab test does not take, traced alone: a call, not inlined (the one-ray loop's
   own stack is not then added to the pair's at every place that starts a ray). Closest hit into
   *hit, or (hit NULL) any hit into *occluded. */
__attribute__((target("avx2,fma,popcnt"), noinline)) static void
bvh__pair_alone(const bvh_tree *tree, const bvh_ray *ray, bvh_hit *hit, uint8_t *occluded) {
    if (hit)
        bvh__trace8(tree, ray, NULL, NULL, 0.0f, hit, NULL, 0, 1);
    else
        *occluded = (uint8_t)bvh__trace8(tree, ray, NULL, NULL, 0.0f, NULL, NULL, 1, 1);
}
/* Ray k of rays into s, its state into *tbest (the caller zeroes cur, lc and sp): 1, or 0 when the
   fast slab test does not take it (then traced alone here, its result written) or it takes no
   box. hits for closest hit, occluded for any hit (any). */
__attribute__((target("avx2,fma,popcnt"))) BVH__INLINE int bvh__pair_start(const bvh_tree *tree, const bvh_ray *rays,
                                                                           bvh_hit *hits, uint8_t *occluded, size_t k,
                                                                           bvh__pair_ray *s, float *tbest, int any) {
    const bvh_ray *ray = &rays[k];
    if (!bvh__ray8_start(ray, &s->rx, &s->q, 0) || !s->q.fast) {
        bvh__pair_alone(tree, ray, any ? NULL : &hits[k], any ? &occluded[k] : NULL);
        return 0;
    }
    s->reach = bvh__trace8_reach(tree, &s->rx);
    s->best.t = *tbest = ray->tmax;
    s->best.u = s->best.v = 0.0f;
    s->best.prim = BVH_INVALID;
    s->best.pk = NULL;
    s->best.lane = 0;
    s->sheared = 0;
    s->idx = k;
    return 1;
}
/* One step of ray s (bvh__traverse8_body's loop once round; fast, the slab test's form, and any,
   constants where inlined): 0 when the ray is done, its result written (as bvh__trace8 and the
   batch write it). */
__attribute__((target("avx2,fma,popcnt"))) BVH__INLINE int
bvh__pair_step(const bvh_node8 *nodes, const bvh_tri4 *tri4, bvh__pair_ray *s, bvh_hit *hits, uint8_t *occluded,
               uint32_t *cur, uint32_t *lc, uint32_t *sp, float *tbest, int fast, int any) {
    if (!*lc) {
        const bvh_node8 *n = &nodes[*cur];
        float tn[BVH__W];
        unsigned m, i0, i1;
        BVH__PREFETCH(n->child);
        m = bvh__slab8_avx2(&s->q, n, *tbest, tn, fast, s->reach);
        if (m) {
            i0 = BVH__CTZ(m);
            m &= m - 1;
            if (m) {
                if (*sp + BVH__W > sizeof s->stack / sizeof s->stack[0]) goto done; /* deeper than builders make */
                i1 = BVH__CTZ(m);
                m &= m - 1;
                if (any) { /* in slot order (leaf slots first), the last pushed first */
                    m |= 1u << i1;
                    while (m) {
                        i1 = BVH__TOP_BIT(m);
                        m &= ~(1u << i1);
                        bvh__push8(nodes, tri4, n, i1, tn, s->stack, sp, 1, 1);
                    }
                } else if (!m) { /* two: the farther one waits */
                    if (tn[i1] < tn[i0]) {
                        unsigned x = i0;
                        i0 = i1;
                        i1 = x;
                    }
                    bvh__push8(nodes, tri4, n, i1, tn, s->stack, sp, 1, 0);
                } else { /* three or more: nearest first, by rank */
                    uint32_t idx[BVH__W], k, j;
                    k = bvh__order8_avx2(tn, m | 1u << i0 | 1u << i1, idx);
                    for (j = k - 1; j > 0; j--) bvh__push8(nodes, tri4, n, idx[j], tn, s->stack, sp, 1, 0);
                    i0 = idx[0];
                }
            }
            *cur = n->child[i0];
            *lc = n->count[i0];
            return 1;
        }
    } else { /* a leaf: its packets */
        if (!s->sheared) {
            bvh__ray_shear(&s->rx);
            bvh__tri8_setup(&s->rx, &s->tr8);
            s->sheared = 1;
        }
        if (bvh__packets_avx2(&s->rx, &s->tr8, tri4 + *cur, *lc, &s->best, any)) {
            if (any) goto done;
            *tbest = s->best.t;
        }
    }
    while (*sp) { /* the next entry still in reach of the best (any hit: every one) */
        --*sp;
        if (any || s->stack[*sp].t <= *tbest) {
            *cur = s->stack[*sp].child;
            *lc = s->stack[*sp].count;
            return 1;
        }
    }
done:
    if (any) {
        occluded[s->idx] = (uint8_t)(s->best.prim != BVH_INVALID);
    } else {
        bvh_hit *h = &hits[s->idx];
        if (s->best.prim == BVH_INVALID) {
            h->t = *tbest;
            h->u = h->v = 0.0f;
            h->prim = BVH_INVALID;
        } else {
            h->t = s->best.t;
            h->u = s->best.u;
            h->v = s->best.v;
            h->prim = s->best.prim;
        }
    }
    return 0;
}
/* Rays i..e in turns, two at a time (fast and any: constants where inlined). */
__attribute__((target("avx2,fma,popcnt"))) BVH__INLINE void bvh__pair_range(const bvh_tree *tree, const bvh_ray *rays,
                                                                            bvh_hit *hits, uint8_t *occluded, size_t i,
                                                                            size_t e, int fast, int any) {
    bvh__pair_ray a, b;
    const bvh_node8 *nodes = tree->nodes8;
    const bvh_tri4 *tri4 = tree->tri4;
    uint32_t cur_a = 0, lc_a = 0, sp_a = 0, cur_b = 0, lc_b = 0, sp_b = 0;
    float tb_a = 0.0f, tb_b = 0.0f;
    int live_a = 0, live_b = 0;
    while (i < e && !live_a) live_a = bvh__pair_start(tree, rays, hits, occluded, i++, &a, &tb_a, any);
    while (i < e && !live_b) live_b = bvh__pair_start(tree, rays, hits, occluded, i++, &b, &tb_b, any);
    while (live_a | live_b) {
        if (live_a && !bvh__pair_step(nodes, tri4, &a, hits, occluded, &cur_a, &lc_a, &sp_a, &tb_a, fast, any)) {
            cur_a = lc_a = sp_a = 0;
            live_a = 0;
            while (i < e && !live_a) live_a = bvh__pair_start(tree, rays, hits, occluded, i++, &a, &tb_a, any);
        }
        if (live_b && !bvh__pair_step(nodes, tri4, &b, hits, occluded, &cur_b, &lc_b, &sp_b, &tb_b, fast, any)) {
            cur_b = lc_b = sp_b = 0;
            live_b = 0;
            while (i < e && !live_b) live_b = bvh__pair_start(tree, rays, hits, occluded, i++, &b, &tb_b, any);
        }
    }
}
/* bvh__pair_range for the CPU's form of the fast slab test, closest hit and any hit; functions of
   their own, beside the one-ray loops, which stay as they were. */
__attribute__((target("avx2,fma,popcnt"), flatten)) static void
bvh__closest8_pairs_avx2(const bvh_tree *tree, const bvh_ray *rays, bvh_hit *hits, size_t i, size_t e) {
    if (bvh__slab_float())
        bvh__pair_range(tree, rays, hits, NULL, i, e, 2, 0);
    else
        bvh__pair_range(tree, rays, hits, NULL, i, e, 1, 0);
}
__attribute__((target("avx2,fma,popcnt"), flatten)) static void
bvh__any8_pairs_avx2(const bvh_tree *tree, const bvh_ray *rays, uint8_t *occluded, size_t i, size_t e) {
    if (bvh__slab_float())
        bvh__pair_range(tree, rays, NULL, occluded, i, e, 2, 1);
    else
        bvh__pair_range(tree, rays, NULL, occluded, i, e, 1, 1);
}
/* A batch's range of closest-hit rays in one call, each ray's set-up and loop inlined: short rays
   (a scene seen from outside, camera rays) no longer pay a call and its saved registers each.
   Any-hit rays keep the call a ray: in this form their loop lost 1-3% on long rays (docs/bench).
   Each ray asks for the lines of the ray and the hit BVH__RAY_AHEAD places on: a camera ray
   takes 25-40 ns, and on that slow a stream, among the nodes' random lines, the cores' own
   prefetchers did not keep up (camera rays 1.04-1.21x as fast; without it a range's length moved
   them by up to 17%: docs/bench 0.9.22). Longer rays neither gain nor lose by it. */
#define BVH__RAY_AHEAD 32u
__attribute__((target("avx2,fma,popcnt"), flatten)) static void
bvh__closest8_range_avx2(const bvh_tree *tree, const bvh_ray *rays, bvh_hit *hits, size_t i, size_t e) {
    for (; i < e; i++) {
        if (i + BVH__RAY_AHEAD < e) {
            BVH__PREFETCH(&rays[i + BVH__RAY_AHEAD]);
            BVH__PREFETCH(&hits[i + BVH__RAY_AHEAD]);
        }
        bvh__trace8(tree, &rays[i], NULL, NULL, 0.0f, &hits[i], NULL, 0, 1);
    }
}
#endif
static int bvh__closest8_base(const bvh_tree *tree, const bvh_ray *ray, bvh__rayx *rx, const bvh__ray8 *q, float tmax,
                              bvh_hit *hit, bvh__best *loc) {
    return bvh__trace8(tree, ray, rx, q, tmax, hit, loc, 0, 0);
}
static int bvh__any8_base(const bvh_tree *tree, const bvh_ray *ray, bvh__rayx *rx, const bvh__ray8 *q, float tmax) {
    return bvh__trace8(tree, ray, rx, q, tmax, NULL, NULL, 1, 0);
}
/* bvh__trace8 for the ISA isa (a constant where inlined). */
BVH__INLINE int bvh__trace8_isa(const bvh_tree *tree, const bvh_ray *ray, bvh__rayx *rx, const bvh__ray8 *q, float tmax,
                                bvh_hit *hit, bvh__best *loc, int any, int isa) {
#ifdef BVH__AVX2
    if (isa) return any ? bvh__any8_avx2(tree, ray, rx, q, tmax) : bvh__closest8_avx2(tree, ray, rx, q, tmax, hit, loc);
#endif
    (void)isa;
    return any ? bvh__any8_base(tree, ray, rx, q, tmax) : bvh__closest8_base(tree, ray, rx, q, tmax, hit, loc);
}
/* The wide traversal for the single-ray calls and the batches, on the CPU's ISA: tree->nodes8 is
   set only on a tree with triangles and nodes (bvh__make_wide), which is all bvh__traverse
   checks first. */
BVH__INLINE int bvh__traverse8_at(const bvh_tree *tree, const bvh_ray *ray, bvh_hit *hit, bvh__best *loc, int any) {
#ifdef BVH__AVX2
    if (bvh__have_avx2()) return bvh__trace8_isa(tree, ray, NULL, NULL, 0.0f, hit, loc, any, 1);
#endif
    return bvh__trace8_isa(tree, ray, NULL, NULL, 0.0f, hit, loc, any, 0);
}
BVH__INLINE int bvh__traverse8(const bvh_tree *tree, const bvh_ray *ray, bvh_hit *hit, int any) {
    return bvh__traverse8_at(tree, ray, hit, NULL, any);
}

/* == the binary traversal with a leaf step ===================================================== */
/* One loop for every kind of primitive a binary tree can hold: it culls nodes by the best t so
   far (ray->tmax, which only decreases) and hands each reference of a leaf it reaches to a leaf
   step, which tests the primitive, keeps the best hit by its own rule and lowers ray->tmax to it.
   Triangles of a binary-only tree (trace_width 2, bvh_intersect_counted), custom primitives and
   instances plug in here; the 8-wide traversal is the default triangle path. Visiting order:
   near child first. */
/* Tests reference `ref` of the tree, primitive `prim` (the caller's index, tree.prims[ref]);
   returns 1 when it took a hit as the new best and set ray->tmax to its t (ties: ray->tmax
   unchanged). rx is the ray as the slab test has it (a triangle step adds the shear). */
typedef int (*bvh__leaf_step)(void *ctx, bvh_ray *ray, bvh__rayx *rx, uint32_t ref, uint32_t prim);

/* Returns 1 if a leaf step took a hit; any: stops at the first. The caller's ray is copied:
   the steps see it with tmax lowered to the best t. visited, when given, gets the number of
   nodes whose box was tested. Inlined, so that each step is called directly. */
BVH__INLINE int bvh__trace_leaves(const bvh_tree *tree, const bvh_ray *ray_in, int any, bvh__leaf_step step, void *ctx,
                                  uint32_t *visited) {
    bvh__rayx rx;
    bvh_ray ray = *ray_in;
    uint32_t stack[BVH_MAX_DEPTH + 2], sp = 0, nvis = 1;
    float stack_t[BVH_MAX_DEPTH + 2];
    const bvh_node *nodes = tree->nodes, *node = nodes;
    int found = 0;
    if (!tree->node_count || !bvh__ray_setup(&ray, &rx)) return 0;
    if (bvh__slab(&rx, node, ray.tmax) == BVH_INF) goto out;
    for (;;) {
        if (node->count) {
            uint32_t k, end = node->index + node->count;
            for (k = node->index; k < end; k++) {
                if (!step(ctx, &ray, &rx, k, tree->prims[k])) continue;
                found = 1;
                if (any) goto out;
            }
        } else {
            const bvh_node *c0 = &nodes[node->index], *c1 = c0 + 1;
            float t0 = bvh__slab(&rx, c0, ray.tmax), t1 = bvh__slab(&rx, c1, ray.tmax);
            nvis += 2;
            if (t0 != BVH_INF || t1 != BVH_INF) {
                if (t1 < t0) {
                    const bvh_node *tc = c0;
                    float tt = t0;
                    c0 = c1;
                    c1 = tc;
                    t0 = t1;
                    t1 = tt;
                }
                node = c0;
                if (t1 != BVH_INF) {
                    if (sp == BVH_MAX_DEPTH + 2) goto out; /* deeper than the validator allows */
                    stack_t[sp] = t1;
                    stack[sp++] = (uint32_t)(c1 - nodes);
                }
                continue;
            }
        }
        for (;;) { /* pop the next node still in reach of the current best */
            if (!sp) goto out;
            --sp;
            if (stack_t[sp] <= ray.tmax) {
                node = &nodes[stack[sp]];
                break;
            }
        }
    }
out:
    if (visited) *visited = nvis;
    return found;
}

/* The triangle step: the watertight test, the shear made at the first leaf; ties in t go to
   the lowest primitive index. */
typedef struct bvh__tri_ctx {
    const bvh_tree *tree;
    int sheared;
    bvh__best best;
} bvh__tri_ctx;
static int bvh__tri_step(void *arg, bvh_ray *ray, bvh__rayx *rx, uint32_t ref, uint32_t prim) {
    bvh__tri_ctx *c = BVH__CAST(bvh__tri_ctx *, arg);
    float t, u, v;
    if (!c->sheared) {
        bvh__ray_shear(rx);
        c->sheared = 1;
    }
    if (!bvh__tri_test(rx, c->tree->tris + 9 * (size_t)ref, ray->tmax, &t, &u, &v)) return 0;
    if (t == ray->tmax && prim > c->best.prim) return 0; /* ties: lowest index */
    c->best.t = ray->tmax = t;
    c->best.u = u;
    c->best.v = v;
    c->best.prim = prim;
    return 1;
}
static int bvh__traverse(const bvh_tree *tree, const bvh_ray *ray, bvh_hit *hit, int any, uint32_t *visited) {
    bvh__tri_ctx c;
    if (hit) {
        hit->t = ray ? ray->tmax : BVH_INF;
        hit->u = hit->v = 0.0f;
        hit->prim = BVH_INVALID;
    }
    if (visited) *visited = 0;
    if (!tree || !ray || !tree->node_count || !tree->tris) return 0;
    if (tree->nodes8 && !visited) return bvh__traverse8(tree, ray, hit, any);
    c.tree = tree;
    c.sheared = 0;
    c.best.t = ray->tmax;
    c.best.u = c.best.v = 0.0f;
    c.best.prim = BVH_INVALID;
    if (!bvh__trace_leaves(tree, ray, any, bvh__tri_step, &c, visited)) return 0;
    if (hit) {
        hit->t = c.best.t;
        hit->u = c.best.u;
        hit->v = c.best.v;
        hit->prim = c.best.prim;
    }
    return 1;
}

BVH_API int bvh_intersect(const bvh_tree *tree, const bvh_ray *ray, bvh_hit *hit) {
    if (tree && ray && tree->nodes8 && tree->tris) return bvh__traverse8(tree, ray, hit, 0);
    return bvh__traverse(tree, ray, hit, 0, NULL);
}
BVH_API int bvh_intersect_counted(const bvh_tree *tree, const bvh_ray *ray, bvh_hit *hit, uint32_t *visited) {
    return bvh__traverse(tree, ray, hit, 0, visited);
}
BVH_API int bvh_occluded(const bvh_tree *tree, const bvh_ray *ray) {
    if (tree && ray && tree->nodes8 && tree->tris) return bvh__traverse8(tree, ray, NULL, 1);
    return bvh__traverse(tree, ray, NULL, 1, NULL);
}

typedef struct bvh__batch {
    const bvh_tree *tree;          /* a tree's rays (by custom->intersect where custom is set), or */
    const bvh_custom_desc *custom; /* (bvh_intersect_custom_batch) */
    const bvh_scene *scene;        /* a scene's, with one mask */
    uint32_t mask;
    const bvh_ray *rays;
    bvh_hit *hits;
    bvh_scene_hit *scene_hits;
    uint8_t *occluded;
    size_t count;
    size_t next; /* the first ray no thread has taken */
} bvh__batch;
/* Chunks taken in turn from a shared counter, not fixed shares: the cost of a ray varies by
   orders of magnitude across a frame (a mesh in one part of it), so fixed shares leave threads
   idle (docs/DESIGN.md, Threads). Each chunk is a BVH__BATCH_GUIDE-th of a thread's share of the
   rays left (guided self-scheduling), a multiple of BVH__BATCH_CHUNK rays: long while much is
   left, so that a thread walks long stretches of neighbouring rays, whose nodes its core's caches
   then hold (a camera's two threads on alternate chunks of 1,024 rays each traced 12% slower a
   ray than one thread alone on the bunny, docs/bench 0.9.23), and a range's look-ahead
   (bvh__closest8_range_avx2) runs on; short at the end, so that the threads finish together. */
#define BVH__BATCH_CHUNK 64u
#define BVH__BATCH_GUIDE 4u
/* The length of the next chunk when `left` rays are left for n threads. */
static size_t bvh__batch_len(size_t left, uint32_t n) {
    size_t c = left / ((size_t)BVH__BATCH_GUIDE * n);
    c = c < BVH__BATCH_CHUNK ? BVH__BATCH_CHUNK : (c + BVH__BATCH_CHUNK - 1) / BVH__BATCH_CHUNK * BVH__BATCH_CHUNK;
    return c < left ? c : left;
}
/* The rays [*first, *end) of the next chunk; 0 when none is left. */
static int bvh__batch_take(bvh__batch *b, bvh__team *team, size_t *first, size_t *end) {
    const size_t n = b->count;
    size_t f, c = 0;
#if defined(__GNUC__) || defined(__clang__)
    f = __atomic_load_n(&b->next, __ATOMIC_RELAXED);
    do {
        if (f >= n) return 0;
        c = bvh__batch_len(n - f, team->n);
    } while (!__atomic_compare_exchange_n(&b->next, &f, f + c, 1, __ATOMIC_RELAXED, __ATOMIC_RELAXED));
#else
#ifndef BVH_NO_THREADS
    if (team->n > 1) pthread_mutex_lock(&team->mutex);
#endif
    f = b->next;
    if (f < n) {
        c = bvh__batch_len(n - f, team->n);
        b->next = f + c;
    }
#ifndef BVH_NO_THREADS
    if (team->n > 1) pthread_mutex_unlock(&team->mutex);
#endif
    if (f >= n) return 0;
#endif
    *first = f;
    *end = f + c;
    return 1;
}
/* Rays first .. end - 1 of a batch. A tree with the 8-wide copy (every tree but trace_width 2)
   goes straight to the wide loop, as bvh_intersect does: bvh__traverse's checks and frame (it
   holds the binary path too) cost a camera ray that misses about as much as its own set-up. */
static int bvh__scene_trace(const bvh_scene *scene, const bvh_ray *ray, uint32_t mask, bvh_scene_hit *hit, int isa);
/* A thread's choice for a batch's closest-hit rays where bvh__pair_wanted leaves it open (2):
   its first such range (or ranges, when short) takes BVH__TUNE_SAMPLES samples spread over it,
   BVH__TUNE_RAYS rays each, one half traced in turns and the other one at a time (neighbouring
   pixels' rays, so much the same work; which way first alternating, as the second half finds
   some of the first one's nodes in cache), and the rest of the batch goes in turns when the
   median of the samples' time ratios a ray (in turns over alone) is below BVH__TUNE_GAIN, else
   one ray at a time. Every ray is traced once, and both ways write the same hits (the tests hold
   the two loops equal), so only the speed depends on the clock. (The same rays traced both ways
   measured mostly the cache: the second pass ran up to twice as fast as the first in a
   renderer's cold caches, which swamped a 10% difference; docs/bench, 0.9.24.) Only batches of
   BVH__TUNE_MIN rays a thread or more time themselves; smaller ones, and batches on a caller's
   pool (no thread of the library's keeps the state), trace one ray at a time there. */
#define BVH__TUNE_SAMPLES 8
#define BVH__TUNE_RAYS 512u
#define BVH__TUNE_GAIN 0.97
#ifndef BVH__TUNE_MIN /* private; a test build sets 1, so that its small batches time themselves */
#define BVH__TUNE_MIN 16384u
#endif
typedef struct bvh__pair_tune {
    int state;                       /* samples taken (0 .. BVH__TUNE_SAMPLES - 1), or -1 (decided:
                                        alone), -2 (in turns) */
    double ratio[BVH__TUNE_SAMPLES]; /* the samples' time ratios */
} bvh__pair_tune;
#ifdef BVH__AVX2
/* One sample: rays [f, f + c), half in turns and half one at a time, timed, into tune (which
   decides at the last). */
static void bvh__pair_sample(const bvh__batch *b, size_t f, size_t c, bvh__pair_tune *tune) {
    const bvh_tree *tree = b->tree;
    const int turns_first = tune->state & 1;
    const size_t h = c / 2, m = f + h, e = f + c;
    unsigned long long t0, t1, t2;
    double r = 1.0;
    int k, j;
    t0 = __builtin_ia32_rdtsc();
    if (turns_first)
        bvh__closest8_pairs_avx2(tree, b->rays, b->hits, f, m);
    else
        bvh__closest8_range_avx2(tree, b->rays, b->hits, f, m);
    t1 = __builtin_ia32_rdtsc();
    if (turns_first)
        bvh__closest8_range_avx2(tree, b->rays, b->hits, m, e);
    else
        bvh__closest8_pairs_avx2(tree, b->rays, b->hits, m, e);
    t2 = __builtin_ia32_rdtsc();
    if (h) { /* time a ray each way (a one-ray sample: no answer, 1) */
        const double first = (double)(t1 - t0) / (double)h, second = (double)(t2 - t1) / (double)(c - h);
        r = turns_first ? first / (second + 1.0) : second / (first + 1.0);
    }
    /* an interrupt or a move to another core in one half moves one sample at most this far */
    r = r < 0.5 ? 0.5 : r > 2.0 ? 2.0 : r;
    for (k = tune->state; k > 0 && tune->ratio[k - 1] > r; k--) tune->ratio[k] = tune->ratio[k - 1]; /* sorted */
    tune->ratio[k] = r;
    if (++tune->state < BVH__TUNE_SAMPLES) return;
    j = BVH__TUNE_SAMPLES / 2; /* the median: a sample an interrupt stretched does not move it */
    tune->state = tune->ratio[j - 1] + tune->ratio[j] < 2.0 * BVH__TUNE_GAIN ? -2 : -1;
}
/* Closest-hit rays [i, e) on a tree where bvh__pair_wanted gives 2 (tune NULL: one at a time).
   While tune still samples, the range first takes the samples it holds room for, spread over
   it, then traces the rest the way they chose (one at a time until the last is taken). */
static void bvh__closest8_tuned(const bvh__batch *b, size_t i, size_t e, bvh__pair_tune *tune) {
    size_t at[BVH__TUNE_SAMPLES], to[BVH__TUNE_SAMPLES], len = e - i, ns = 0, k, pos = i;
    if (tune && tune->state >= 0) {
        const size_t want = (size_t)(BVH__TUNE_SAMPLES - tune->state), fit = len / BVH__TUNE_RAYS;
        ns = fit < want ? (fit ? fit : 1) : want;
        for (k = 0; k < ns; k++) { /* sample k: rays [at[k], to[k]) */
            at[k] = i + k * (len / ns);
            to[k] = e - at[k] < BVH__TUNE_RAYS ? e : at[k] + BVH__TUNE_RAYS;
            bvh__pair_sample(b, at[k], to[k] - at[k], tune);
        }
    }
    for (k = 0; k <= ns; k++) { /* the stretches between the samples */
        const size_t end = k < ns ? at[k] : e;
        if (end > pos) {
            if (tune && tune->state == -2)
                bvh__closest8_pairs_avx2(b->tree, b->rays, b->hits, pos, end);
            else
                bvh__closest8_range_avx2(b->tree, b->rays, b->hits, pos, end);
        }
        if (k < ns) pos = to[k];
    }
}
#endif
static int bvh__trace_custom(const bvh_tree *tree, const bvh_ray *ray, bvh_hit *hit, int any,
                             const bvh_custom_desc *custom);
static void bvh__batch_range(const bvh__batch *b, size_t i, size_t e, bvh__pair_tune *tune) {
    const bvh_tree *tree = b->tree;
    const int isa = bvh__have_avx2(); /* the CPU's ISA asked once a range, not once a ray */
    (void)tune;
    if (b->custom) {
        if (b->hits)
            for (; i < e; i++) bvh__trace_custom(tree, &b->rays[i], &b->hits[i], 0, b->custom);
        else
            for (; i < e; i++) b->occluded[i] = (uint8_t)bvh__trace_custom(tree, &b->rays[i], NULL, 1, b->custom);
    } else if (b->scene) {
        if (b->scene_hits)
            for (; i < e; i++) bvh__scene_trace(b->scene, &b->rays[i], b->mask, &b->scene_hits[i], isa);
        else
            for (; i < e; i++) b->occluded[i] = (uint8_t)bvh__scene_trace(b->scene, &b->rays[i], b->mask, NULL, isa);
    } else if (tree->nodes8) {
#ifdef BVH__AVX2
        const int turns = isa ? bvh__pair_wanted(tree, b->rays, i, e, !b->hits) : 0;
        if (turns == 2) { /* closest hit (any hit never gets 2) */
            bvh__closest8_tuned(b, i, e, tune);
            return;
        }
        if (turns) {
            if (b->hits)
                bvh__closest8_pairs_avx2(tree, b->rays, b->hits, i, e);
            else
                bvh__any8_pairs_avx2(tree, b->rays, b->occluded, i, e);
            return;
        }
        if (isa && b->hits) {
            bvh__closest8_range_avx2(tree, b->rays, b->hits, i, e);
            return;
        }
#endif
        if (b->hits)
            for (; i < e; i++) bvh__trace8_isa(tree, &b->rays[i], NULL, NULL, 0.0f, &b->hits[i], NULL, 0, isa);
        else
            for (; i < e; i++)
                b->occluded[i] = (uint8_t)bvh__trace8_isa(tree, &b->rays[i], NULL, NULL, 0.0f, NULL, NULL, 1, isa);
    } else {
        if (b->hits)
            for (; i < e; i++) bvh__traverse(tree, &b->rays[i], &b->hits[i], 0, NULL);
        else
            for (; i < e; i++) b->occluded[i] = (uint8_t)bvh__traverse(tree, &b->rays[i], NULL, 1, NULL);
    }
}
static void bvh__batch_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    bvh__batch *b = BVH__CAST(bvh__batch *, arg);
    bvh__pair_tune tune;
    size_t i, e;
    (void)tid;
    tune.state = b->count / nt >= BVH__TUNE_MIN ? 0 : -1;
    while (bvh__batch_take(b, team, &i, &e)) bvh__batch_range(b, i, e, &tune);
}
#if defined(__GNUC__) || defined(__clang__)
/* Under a caller's pool: task `index` of `tasks` is a thread of bvh__batch_fn, taking guided
   chunks from the shared counter with a tuning of its own, so that it walks long runs of
   neighbouring rays and times its closest-hit rays as the library's threads do (a task per
   64-ray chunk did neither: docs/bench, 0.9.26). A task that finds no chunk left returns, so a
   pool that runs the tasks one after another is still right. */
typedef struct bvh__batch_pooled {
    bvh__batch *b;
    uint32_t tasks;
} bvh__batch_pooled;
static void bvh__batch_pool_task(void *arg, uint32_t index) {
    const bvh__batch_pooled *p = BVH__CAST(const bvh__batch_pooled *, arg);
    bvh__team team; /* only its size, for the chunks' length: the atomic counter needs no lock */
    memset(&team, 0, sizeof team);
    team.n = p->tasks;
    bvh__batch_fn(p->b, index, p->tasks, &team);
}
#else
/* Under a caller's pool each chunk is a task (no atomic counter to share): the pool balances them. */
static void bvh__batch_task(void *arg, uint32_t index) {
    const bvh__batch *b = BVH__CAST(const bvh__batch *, arg);
    size_t i = (size_t)index * BVH__BATCH_CHUNK, e = i + BVH__BATCH_CHUNK < b->count ? i + BVH__BATCH_CHUNK : b->count;
    bvh__batch_range(b, i, e, NULL);
}
#endif
/* Batch b (its rays, outputs and count set) on the caller's pool, or on threads of the library's
   own (allocator: their bookkeeping). */
static bvh_result bvh__batch_go(bvh__batch *b, const bvh_allocator *allocator, uint32_t threads,
                                const bvh_thread_pool *pool) {
    const size_t count = b->count;
    uint32_t nt = bvh__resolve_threads(threads);
    if ((size_t)nt * 256 > count) nt = (uint32_t)((count + 255) / 256);
    if (nt < 1) nt = 1;
    b->next = 0;
#if defined(__GNUC__) || defined(__clang__)
    if (pool && pool->run) { /* nt tasks (0 = online CPUs), each a thread's loop */
        bvh__batch_pooled p;
        p.b = b;
        p.tasks = nt;
        if (count) pool->run(pool->user, nt, bvh__batch_pool_task, &p);
        return BVH_SUCCESS;
    }
#else
    if (pool && pool->run) { /* the pool's own scheduling keeps neighbouring tasks together */
        const bvh__batch all = *b;
        size_t chunks = (count + BVH__BATCH_CHUNK - 1) / BVH__BATCH_CHUNK, done;
        (void)threads;                   /* the pool balances the chunks itself */
        for (done = 0; done < chunks;) { /* runs of at most 2^32 - 1 tasks */
            uint32_t k = chunks - done > 0xffffffffu ? 0xffffffffu : (uint32_t)(chunks - done);
            const size_t first = done * BVH__BATCH_CHUNK;
            b->rays = all.rays + first;
            b->hits = all.hits ? all.hits + first : NULL;
            b->scene_hits = all.scene_hits ? all.scene_hits + first : NULL;
            b->occluded = all.occluded ? all.occluded + first : NULL;
            b->count = count - first;
            pool->run(pool->user, k, bvh__batch_task, b);
            done += k;
        }
        return BVH_SUCCESS;
    }
#endif
    return bvh__team_run(allocator, nt, bvh__batch_fn, b);
}
/* A batch of count rays, any-hit flags to occ (or NULL): the fields every batch has, the rest
   zero for the caller to set (a tree or a scene, and where closest hits go). */
static void bvh__batch_init(bvh__batch *b, const bvh_ray *rays, uint8_t *occ, size_t count) {
    memset(b, 0, sizeof *b);
    b->rays = rays;
    b->occluded = occ;
    b->count = count;
}
/* A tree's batch (by the custom test where custom is set) through bvh__batch_go; the caller has
   checked the arguments. */
static bvh_result bvh__tree_batch_go(const bvh_tree *tree, const bvh_custom_desc *custom, const bvh_ray *rays,
                                     bvh_hit *hits, uint8_t *occ, size_t count, uint32_t threads,
                                     const bvh_thread_pool *pool) {
    bvh__batch b;
    bvh__batch_init(&b, rays, occ, count);
    b.tree = tree;
    b.custom = custom;
    b.hits = hits;
    return bvh__batch_go(&b, &tree->allocator, threads, pool);
}
static bvh_result bvh__batch_run(const bvh_tree *tree, const bvh_ray *rays, bvh_hit *hits, uint8_t *occ, size_t count,
                                 uint32_t threads, const bvh_thread_pool *pool) {
    if (!tree || (count && (!rays || (!hits && !occ)))) return BVH_ERROR_INVALID_ARGUMENT;
    if (!bvh__allocator_paired(&tree->allocator)) return BVH_ERROR_INVALID_ARGUMENT;
    if (tree->node_count && !tree->tris) { /* as the single-ray calls: every ray misses */
        size_t i;
        for (i = 0; i < count; i++) {
            if (hits)
                bvh__traverse(tree, &rays[i], &hits[i], 0, NULL);
            else
                occ[i] = 0;
        }
        return BVH_ERROR_NO_TRIANGLES;
    }
    return bvh__tree_batch_go(tree, NULL, rays, hits, occ, count, threads, pool);
}
/* The four batch calls: the output the call writes (hits or occluded) must be given when there
   are rays; desc NULL = threads 0 (all CPUs) and no pool. */
static bvh_result bvh__batch_call(const bvh_tree *tree, const bvh_ray *rays, bvh_hit *hits, uint8_t *occluded,
                                  size_t count, uint32_t threads, const bvh_thread_pool *pool) {
    if (!hits && !occluded && count) return BVH_ERROR_INVALID_ARGUMENT;
    return bvh__batch_run(tree, rays, hits, occluded, count, threads, pool);
}
BVH_API bvh_result bvh_intersect_batch(const bvh_tree *tree, const bvh_ray *rays, bvh_hit *hits, size_t count,
                                       uint32_t threads) {
    return bvh__batch_call(tree, rays, hits, NULL, count, threads, NULL);
}
BVH_API bvh_result bvh_occluded_batch(const bvh_tree *tree, const bvh_ray *rays, uint8_t *occluded, size_t count,
                                      uint32_t threads) {
    return bvh__batch_call(tree, rays, NULL, occluded, count, threads, NULL);
}
BVH_API bvh_result bvh_intersect_batch_ex(const bvh_tree *tree, const bvh_ray *rays, bvh_hit *hits, size_t count,
                                          const bvh_batch_desc *desc) {
    return bvh__batch_call(tree, rays, hits, NULL, count, desc ? desc->threads : 0, desc ? &desc->pool : NULL);
}
BVH_API bvh_result bvh_occluded_batch_ex(const bvh_tree *tree, const bvh_ray *rays, uint8_t *occluded, size_t count,
                                         const bvh_batch_desc *desc) {
    return bvh__batch_call(tree, rays, NULL, occluded, count, desc ? desc->threads : 0, desc ? &desc->pool : NULL);
}

/* ============================================================================================ */
/* == custom primitives: the caller's test as the leaf step of bvh__trace_leaves ================ */
/* ============================================================================================ */
typedef struct bvh__custom_ctx {
    const bvh_custom_desc *custom;
    bvh_hit best; /* prim BVH_INVALID until a hit is taken */
} bvh__custom_ctx;
/* The callback's hit is taken if its t is in [tmin, tmax] (NaN and +inf never are) and, at
   t == tmax, only from a lower index than the best's: ties go to the lowest index whatever the
   visiting order. Before any hit, best.prim is BVH_INVALID, above every index. */
static int bvh__custom_step(void *arg, bvh_ray *ray, bvh__rayx *rx, uint32_t ref, uint32_t prim) {
    bvh__custom_ctx *c = BVH__CAST(bvh__custom_ctx *, arg);
    bvh_hit h;
    (void)rx;
    (void)ref;
    h.t = ray->tmax;
    h.u = h.v = 0.0f;
    h.prim = prim;
    if (!c->custom->intersect(ray, prim, c->custom->user, &h)) return 0;
    if (!(h.t >= ray->tmin && h.t <= ray->tmax && h.t < BVH_INF)) return 0;
    if (h.t == ray->tmax && prim > c->best.prim) return 0;
    h.prim = prim;
    c->best = h;
    ray->tmax = h.t;
    return 1;
}
static int bvh__trace_custom(const bvh_tree *tree, const bvh_ray *ray, bvh_hit *hit, int any,
                             const bvh_custom_desc *custom) {
    bvh__custom_ctx c;
    int found = 0;
    c.custom = custom;
    c.best.t = ray ? ray->tmax : BVH_INF;
    c.best.u = c.best.v = 0.0f;
    c.best.prim = BVH_INVALID;
    if (tree && ray && custom && custom->intersect)
        found = bvh__trace_leaves(tree, ray, any, bvh__custom_step, &c, NULL);
    if (hit) *hit = c.best;
    return found;
}
BVH_API int bvh_intersect_custom(const bvh_tree *tree, const bvh_ray *ray, bvh_hit *hit,
                                 const bvh_custom_desc *custom) {
    return bvh__trace_custom(tree, ray, hit, 0, custom);
}
BVH_API int bvh_occluded_custom(const bvh_tree *tree, const bvh_ray *ray, const bvh_custom_desc *custom) {
    return bvh__trace_custom(tree, ray, NULL, 1, custom);
}

/* The batch calls: bvh__batch_go with the custom test (see bvh__batch_range). */
static bvh_result bvh__custom_batch_run(const bvh_tree *tree, const bvh_ray *rays, bvh_hit *hits, uint8_t *occ,
                                        size_t count, const bvh_custom_desc *custom, uint32_t threads,
                                        const bvh_thread_pool *pool) {
    if (!tree || !custom || !custom->intersect || (count && (!rays || (!hits && !occ))))
        return BVH_ERROR_INVALID_ARGUMENT;
    if (!bvh__allocator_paired(&tree->allocator)) return BVH_ERROR_INVALID_ARGUMENT;
    return bvh__tree_batch_go(tree, custom, rays, hits, occ, count, threads, pool);
}
BVH_API bvh_result bvh_intersect_custom_batch(const bvh_tree *tree, const bvh_ray *rays, bvh_hit *hits, size_t count,
                                              uint32_t threads, const bvh_custom_desc *custom) {
    if (!hits && count) return BVH_ERROR_INVALID_ARGUMENT;
    return bvh__custom_batch_run(tree, rays, hits, NULL, count, custom, threads, NULL);
}
BVH_API bvh_result bvh_occluded_custom_batch(const bvh_tree *tree, const bvh_ray *rays, uint8_t *occluded, size_t count,
                                             uint32_t threads, const bvh_custom_desc *custom) {
    if (!occluded && count) return BVH_ERROR_INVALID_ARGUMENT;
    return bvh__custom_batch_run(tree, rays, NULL, occluded, count, custom, threads, NULL);
}
BVH_API bvh_result bvh_intersect_custom_batch_ex(const bvh_tree *tree, const bvh_ray *rays, bvh_hit *hits, size_t count,
                                                 const bvh_custom_desc *custom, const bvh_batch_desc *desc) {
    if (!hits && count) return BVH_ERROR_INVALID_ARGUMENT;
    return bvh__custom_batch_run(tree, rays, hits, NULL, count, custom, desc ? desc->threads : 0,
                                 desc ? &desc->pool : NULL);
}
BVH_API bvh_result bvh_occluded_custom_batch_ex(const bvh_tree *tree, const bvh_ray *rays, uint8_t *occluded,
                                                size_t count, const bvh_custom_desc *custom,
                                                const bvh_batch_desc *desc) {
    if (!occluded && count) return BVH_ERROR_INVALID_ARGUMENT;
    return bvh__custom_batch_run(tree, rays, NULL, occluded, count, custom, desc ? desc->threads : 0,
                                 desc ? &desc->pool : NULL);
}

/* ============================================================================================ */
/* == secondary rays: origin offset, hit point and normal ======================================= */
/* Waechter & Binder, "A Fast and Robust Method for Avoiding Self-Intersection" (Ray Tracing Gems,
   2019, ch. 6): each coordinate of p moves away from the surface by an integer number of ulps
   proportional to n's component (BVH__OFFSET_INT ulps for a unit component), which scales with
   |p| as the rounding error of p does; within BVH__OFFSET_ORIGIN of 0 on an axis, where ulps
   become tiny while the error stays that of the vertices (of the scene's scale), the move is an
   absolute BVH__OFFSET_FLOAT * n instead. The constants are the paper's. */
/* ============================================================================================ */
#define BVH__OFFSET_ORIGIN (1.0f / 32.0f)
#define BVH__OFFSET_FLOAT (1.0f / 65536.0f)
#define BVH__OFFSET_INT 256.0f
static float bvh__offset1(float p, float n) {
    uint32_t u;
    int32_t k;
    float q;
    if (!bvh__finite(p) || bvh__nan(n)) return p;
    n = n > 1.0f ? 1.0f : n < -1.0f ? -1.0f : n; /* a unit normal's rounding, or a longer one */
    if (fabsf(p) < BVH__OFFSET_ORIGIN) return p + BVH__OFFSET_FLOAT * n;
    k = (int32_t)(BVH__OFFSET_INT * n); /* |k| <= 256 */
    /* the bits of a float grow with its magnitude: toward +n on the positive side means more
       bits, on the negative side fewer (unsigned arithmetic: no signed overflow) */
    u = bvh__bits(p);
    u = p < 0.0f ? u - (uint32_t)k : u + (uint32_t)k;
    memcpy(&q, &u, sizeof q);
    return bvh__finite(q) ? q : p; /* past FLT_MAX: p itself (no finite float lies farther) */
}
BVH_API bvh_vec3 bvh_offset_origin(bvh_vec3 p, bvh_vec3 n) {
    bvh_vec3 r;
    r.x = bvh__offset1(p.x, n.x);
    r.y = bvh__offset1(p.y, n.y);
    r.z = bvh__offset1(p.z, n.z);
    return r;
}
BVH_API bvh_result bvh_hit_surface(const bvh_triangles *mesh, const bvh_hit *hit, bvh_vec3 *point, bvh_vec3 *normal) {
    float t[9], w, e1[3], e2[3];
    double nx, ny, nz, l;
    int k;
    if (!mesh || !hit || !mesh->positions || (mesh->stride && mesh->stride < 3 * sizeof(float)))
        return BVH_ERROR_INVALID_ARGUMENT;
    if (hit->prim >= mesh->triangle_count) return BVH_ERROR_INVALID_ARGUMENT; /* BVH_INVALID too */
    if ((uintptr_t)mesh->indices % sizeof(uint32_t)) return BVH_ERROR_INVALID_ARGUMENT;
    if (mesh->indices) {
        for (k = 0; k < 3; k++)
            if (mesh->indices[3 * (size_t)hit->prim + k] >= mesh->vertex_count) return BVH_ERROR_INDEX_OUT_OF_RANGE;
    } else if (3 * (uint64_t)hit->prim + 2 >= mesh->vertex_count) {
        return BVH_ERROR_INDEX_OUT_OF_RANGE;
    }
    bvh__fetch_triangle(mesh, hit->prim, t);
    if (point) {
        w = 1.0f - hit->u - hit->v;
        point->x = w * t[0] + hit->u * t[3] + hit->v * t[6];
        point->y = w * t[1] + hit->u * t[4] + hit->v * t[7];
        point->z = w * t[2] + hit->u * t[5] + hit->v * t[8];
    }
    if (normal) { /* the cross product in double: no overflow for large, no underflow for tiny triangles */
        for (k = 0; k < 3; k++) {
            e1[k] = t[3 + k] - t[k];
            e2[k] = t[6 + k] - t[k];
        }
        nx = (double)e1[1] * e2[2] - (double)e1[2] * e2[1];
        ny = (double)e1[2] * e2[0] - (double)e1[0] * e2[2];
        nz = (double)e1[0] * e2[1] - (double)e1[1] * e2[0];
        l = sqrt(nx * nx + ny * ny + nz * nz);
        if (!(l > 0.0)) { /* zero area (or a NaN vertex): no normal */
            l = 1.0;
            nx = ny = nz = 0.0;
        }
        normal->x = (float)(nx / l);
        normal->y = (float)(ny / l);
        normal->z = (float)(nz / l);
    }
    return BVH_SUCCESS;
}

/* ============================================================================================ */
/* == instances: two-level scenes ================================================================ */
/* The top level is a box tree over the instances' world boxes (tree.nodes, for OpenCL and the
   caller), traced on the CPU through its 8-wide copy (bvh_scene.top8) by the 8-wide loop with a
   leaf step that skips instances by mask, transforms the ray into the instance's space and
   traces the bottom-level tree there (its 8-wide layout where it has one, for the same ISA). The best hit keeps the
   instance, the mesh's triangle and t; the normal of the final hit is computed from the tree's copy of the triangle
   (tree.tris, in reference order), found by a map from triangle to reference that the scene makes once per distinct
   bottom-level tree (walking the tree again to find it would cost about as much as the trace). */
/* ============================================================================================ */
BVH__INLINE bvh_ray bvh__ray_transform(const bvh_ray *ray, const float *m) {
    bvh_ray r = *ray;
    const bvh_vec3 o = ray->origin, d = ray->dir;
    r.origin.x = m[0] * o.x + m[1] * o.y + m[2] * o.z + m[3];
    r.origin.y = m[4] * o.x + m[5] * o.y + m[6] * o.z + m[7];
    r.origin.z = m[8] * o.x + m[9] * o.y + m[10] * o.z + m[11];
    r.dir.x = m[0] * d.x + m[1] * d.y + m[2] * d.z;
    r.dir.y = m[4] * d.x + m[5] * d.y + m[6] * d.z;
    r.dir.z = m[8] * d.x + m[9] * d.y + m[10] * d.z;
    return r;
}
BVH_API bvh_ray bvh_ray_transform(const bvh_ray *ray, const float m[12]) { return bvh__ray_transform(ray, m); }
/* The inverse of a 3x4 affine transform, in double, rounded to float; 0 if m is not finite or
   singular (a zero determinant, or an inverse that is not finite in float). */
static int bvh__invert34(const float m[12], float out[12]) {
    double a[9], inv[9], det, t[3];
    int i;
    for (i = 0; i < 12; i++)
        if (!bvh__finite(m[i])) return 0;
    for (i = 0; i < 9; i++) a[i] = m[(i / 3) * 4 + i % 3];
    inv[0] = a[4] * a[8] - a[5] * a[7];
    inv[1] = a[2] * a[7] - a[1] * a[8];
    inv[2] = a[1] * a[5] - a[2] * a[4];
    inv[3] = a[5] * a[6] - a[3] * a[8];
    inv[4] = a[0] * a[8] - a[2] * a[6];
    inv[5] = a[2] * a[3] - a[0] * a[5];
    inv[6] = a[3] * a[7] - a[4] * a[6];
    inv[7] = a[1] * a[6] - a[0] * a[7];
    inv[8] = a[0] * a[4] - a[1] * a[3];
    det = a[0] * inv[0] + a[1] * inv[3] + a[2] * inv[6];
    if (det == 0.0) return 0;
    for (i = 0; i < 9; i++) inv[i] /= det;
    for (i = 0; i < 3; i++) t[i] = -(inv[3 * i] * m[3] + inv[3 * i + 1] * m[7] + inv[3 * i + 2] * m[11]);
    for (i = 0; i < 12; i++) {
        double x = i % 4 == 3 ? t[i / 4] : inv[(i / 4) * 3 + i % 4];
        out[i] = (float)x;
        if (!bvh__finite(out[i])) return 0;
    }
    return 1;
}
/* The world box of an instance: the bottom-level root box's corners transformed in double, then
   widened by 2^-20 of the largest coordinate (and rounded outward): the traversal tests the
   world ray against it and the float-transformed ray against the tree below, whose roundings
   differ; the margin keeps every hit of the latter inside the former. */
static bvh_aabb bvh__instance_box(const bvh_instance *in) {
    bvh_aabb b = bvh_tree_bounds(in->tree), w;
    double lo[3] = {DBL_MAX, DBL_MAX, DBL_MAX}, hi[3] = {-DBL_MAX, -DBL_MAX, -DBL_MAX}, pad = 0.0;
    const float *m = in->transform;
    int c, i;
    if (!bvh__nonempty(b)) return b;
    for (c = 0; c < 8; c++) {
        double p[3];
        p[0] = c & 1 ? b.max.x : b.min.x;
        p[1] = c & 2 ? b.max.y : b.min.y;
        p[2] = c & 4 ? b.max.z : b.min.z;
        for (i = 0; i < 3; i++) {
            double x =
                (double)m[4 * i] * p[0] + (double)m[4 * i + 1] * p[1] + (double)m[4 * i + 2] * p[2] + m[4 * i + 3];
            lo[i] = x < lo[i] ? x : lo[i];
            hi[i] = x > hi[i] ? x : hi[i];
        }
    }
    for (i = 0; i < 3; i++) {
        pad = fabs(lo[i]) > pad ? fabs(lo[i]) : pad;
        pad = fabs(hi[i]) > pad ? fabs(hi[i]) : pad;
    }
    pad *= 9.5367431640625e-7; /* 2^-20 */
    for (i = 0; i < 3; i++) {
        float l = (float)(lo[i] - pad), h = (float)(hi[i] + pad);
        if ((double)l > lo[i] - pad) l = nextafterf(l, -BVH_INF);
        if ((double)h < hi[i] + pad) h = nextafterf(h, BVH_INF);
        bvh__set(&w.min, i, l);
        bvh__set(&w.max, i, h);
    }
    return w;
}
BVH_API void bvh_scene_free(bvh_scene *scene) {
    bvh_allocator al;
    if (!scene) return;
    al = scene->allocator;
    bvh_free(&scene->top);
    bvh__free(&al, scene->instances);
    bvh__free(&al, scene->inverse);
    bvh__free(&al, scene->boxes);
    bvh__free(&al, scene->top8);
    bvh__free(&al, scene->mesh);
    bvh__free(&al, scene->ref_base);
    bvh__free(&al, scene->ref_of_prim);
    memset(scene, 0, sizeof *scene);
    scene->allocator = al;
}
/* Numbers the distinct trees of the instances (an open-addressing table on the pointers: O(n)
   for any number of instances) and makes each one's triangle-to-reference map. */
static bvh_result bvh__scene_maps(bvh_scene *sc) {
    uint32_t n = sc->instance_count, cap = 16, i, m = 0, *slot;
    const bvh_tree **keys;
    size_t total = 0, k;
    bvh_result r = BVH_SUCCESS;
    while (cap < 2 * (size_t)n) cap *= 2;
    keys = BVH__ALLOC(&sc->allocator, const bvh_tree *, cap);
    slot = BVH__ALLOC(&sc->allocator, uint32_t, cap);
    sc->mesh = BVH__ALLOC(&sc->allocator, uint32_t, n ? n : 1);
    if (!keys || !slot || !sc->mesh) r = BVH_ERROR_OUT_OF_MEMORY;
    if (r == BVH_SUCCESS) {
        for (i = 0; i < cap; i++) keys[i] = NULL;
        for (i = 0; i < n; i++) {
            const bvh_tree *t = sc->instances[i].tree;
            uint32_t h = (uint32_t)(((uint64_t)(uintptr_t)t * 0x9E3779B97F4A7C15ull) >> 40) & (cap - 1);
            while (keys[h] && keys[h] != t) h = (h + 1) & (cap - 1);
            if (!keys[h]) {
                keys[h] = t;
                slot[h] = m++;
            }
            sc->mesh[i] = slot[h];
        }
        sc->mesh_count = m;
        sc->ref_base = BVH__ALLOC(&sc->allocator, size_t, m ? m : 1);
        if (!sc->ref_base) r = BVH_ERROR_OUT_OF_MEMORY;
    }
    if (r == BVH_SUCCESS) {
        for (i = 0; i < cap; i++)
            if (keys[i]) sc->ref_base[slot[i]] = keys[i]->prim_count;
        for (i = 0; i < m; i++) {
            size_t c = sc->ref_base[i];
            sc->ref_base[i] = total;
            total += c;
        }
        sc->ref_of_prim = BVH__ALLOC(&sc->allocator, uint32_t, total ? total : 1);
        if (!sc->ref_of_prim) r = BVH_ERROR_OUT_OF_MEMORY;
    }
    if (r == BVH_SUCCESS)
        for (i = 0; i < cap; i++) {
            const bvh_tree *t = keys[i];
            uint32_t *map;
            if (!t) continue;
            map = sc->ref_of_prim + sc->ref_base[slot[i]];
            for (k = 0; k < t->ref_count; k++) map[t->prims[k]] = (uint32_t)k; /* any reference will do */
        }
    bvh__free(&sc->allocator, BVH__CAST(void *, keys));
    bvh__free(&sc->allocator, slot);
    return r;
}
/* The top level's 8-wide copy (bvh_scene.top8), so that a ray meets up to eight instance boxes in
   one SIMD test, as in a bottom-level tree. Each wide node is made from an item, a binary
   interior node or a run of a leaf's references, by opening the item of largest surface area
   (a node into its two children, a run into its halves) until there are eight or none can be
   opened; a run of one reference is a leaf slot: that instance, with its own world box (with
   split references a leaf's box may be clipped; the whole instance box still holds every hit the
   clipped part does). Children after their parent; recursion as deep as the binary tree plus
   log2(BVH__MAX_LEAF). */
#define BVH__TOP_MOVED 1u    /* a top8 leaf slot's count: the ray is transformed into the instance */
#define BVH__TOP_IDENTITY 2u /* ... its transform is the identity (bit for bit): the world ray is it */
static const float bvh__identity34[12] = {1.0f, 0.0f, 0.0f, 0.0f, 0.0f, 1.0f, 0.0f, 0.0f, 0.0f, 0.0f, 1.0f, 0.0f};
typedef struct bvh__top_item {
    uint32_t node;         /* a binary interior node, or BVH_INVALID: ... */
    uint32_t first, count; /* ... references first .. first + count - 1 */
} bvh__top_item;
static bvh__top_item bvh__top8_item(const bvh_tree *top, uint32_t node) {
    bvh__top_item it;
    const bvh_node *n = &top->nodes[node];
    it.node = n->count ? BVH_INVALID : node;
    it.first = n->index;
    it.count = n->count;
    return it;
}
static bvh_aabb bvh__top8_box(const bvh_scene *s, bvh__top_item it) {
    bvh_aabb b = bvh__empty();
    uint32_t k;
    if (it.node != BVH_INVALID) return bvh__node_box(&s->top.nodes[it.node]);
    for (k = it.first; k < it.first + it.count; k++) b = bvh__merge(b, s->boxes[s->top.prims[k]]);
    return b;
}
static uint32_t bvh__top8_node(bvh_scene *s, bvh__top_item it) {
    const uint32_t w = s->top8_count++;
    bvh_node8 *out = &s->top8[w]; /* stays valid: top8 is allocated whole */
    bvh__top_item items[BVH__W];
    bvh_aabb box[BVH__W];
    uint32_t n = 1, i;
    items[0] = it;
    box[0] = bvh__top8_box(s, it);
    while (n < BVH__W) {
        uint32_t best = BVH_INVALID;
        float area = -1.0f;
        for (i = 0; i < n; i++) {
            float ai;
            if (items[i].node == BVH_INVALID && items[i].count < 2) continue; /* an instance */
            ai = bvh__half_area(box[i]);
            if (ai > area) {
                area = ai;
                best = i;
            }
        }
        if (best == BVH_INVALID) break;
        if (items[best].node != BVH_INVALID) {
            const uint32_t c = s->top.nodes[items[best].node].index;
            items[best] = bvh__top8_item(&s->top, c);
            items[n] = bvh__top8_item(&s->top, c + 1);
        } else {
            const uint32_t h = items[best].count / 2;
            items[n] = items[best];
            items[n].first += h;
            items[n].count -= h;
            items[best].count = h;
        }
        box[best] = bvh__top8_box(s, items[best]);
        box[n] = bvh__top8_box(s, items[n]);
        n++;
    }
    bvh__node8_clear(out);
    for (i = 0; i < n; i++) {
        bvh__node8_box(out, i, box[i].min, box[i].max);
        if (items[i].node == BVH_INVALID && items[i].count == 1) {
            const uint32_t inst = s->top.prims[items[i].first];
            out->child[i] = inst;
            out->count[i] = (uint8_t)(memcmp(s->instances[inst].transform, bvh__identity34, sizeof bvh__identity34)
                                          ? BVH__TOP_MOVED
                                          : BVH__TOP_IDENTITY);
        } else {
            out->child[i] = bvh__top8_node(s, items[i]);
        }
    }
    return w;
}
BVH_API bvh_result bvh_scene_build(bvh_scene *scene, const bvh_scene_desc *desc) {
    bvh_build_desc td;
    bvh_aabb *boxes = NULL;
    bvh_result r = BVH_SUCCESS;
    uint32_t i, n;
    if (!scene) return BVH_ERROR_INVALID_ARGUMENT;
    memset(scene, 0, sizeof *scene);
    if (!desc || (desc->instance_count && !desc->instances) || !bvh__allocator_paired(&desc->allocator) ||
        (unsigned)desc->builder >= BVH_BUILDER_COUNT)
        return BVH_ERROR_INVALID_ARGUMENT;
    n = desc->instance_count;
    if (n > BVH__MAX_PRIMS) return BVH_ERROR_TOO_MANY_PRIMITIVES;
    for (i = 0; i < n; i++) {
        const bvh_tree *t = desc->instances[i].tree;
        const bvh_custom_desc *cu = desc->instances[i].custom;
        if (!t || (cu && !cu->intersect) || (t->node_count && !t->tris && !cu)) return BVH_ERROR_INVALID_ARGUMENT;
    }
    scene->allocator = desc->allocator;
    scene->instance_count = n;
    scene->instances = BVH__ALLOC(&scene->allocator, bvh_instance, n ? n : 1);
    scene->inverse = BVH__ALLOC(&scene->allocator, float, 12 * (size_t)(n ? n : 1));
    boxes = BVH__ALLOC(&scene->allocator, bvh_aabb, n ? n : 1);
    if (!scene->instances || !scene->inverse || !boxes) r = BVH_ERROR_OUT_OF_MEMORY;
    for (i = 0; r == BVH_SUCCESS && i < n; i++) {
        scene->instances[i] = desc->instances[i];
        if (!bvh__invert34(desc->instances[i].transform, scene->inverse + 12 * (size_t)i))
            r = BVH_ERROR_INVALID_GEOMETRY;
        else
            boxes[i] = bvh__instance_box(&desc->instances[i]);
    }
    if (r == BVH_SUCCESS) r = bvh__scene_maps(scene);
    if (r == BVH_SUCCESS) {
        memset(&td, 0, sizeof td);
        td.builder = desc->builder;
        td.boxes = boxes;
        td.box_count = n;
        td.threads = desc->threads;
        td.pool = desc->pool;
        td.allocator = desc->allocator;
        td.skip_invalid = 1; /* the empty box of an instance of an empty tree: left out */
        r = bvh_build(&scene->top, &td);
    }
    scene->boxes = boxes; /* freed with the scene, also on failure */
    if (r == BVH_SUCCESS && scene->top.node_count) {
        /* at most one wide node per reference: each but the root opens an item of two or more */
        scene->top8 = BVH__ALLOC(&scene->allocator, bvh_node8, scene->top.ref_count);
        if (!scene->top8)
            r = BVH_ERROR_OUT_OF_MEMORY;
        else
            bvh__top8_node(scene, bvh__top8_item(&scene->top, 0));
    }
    if (r != BVH_SUCCESS) bvh_scene_free(scene);
    return r;
}

typedef struct bvh__scene_ctx {
    const bvh_scene *scene;
    uint32_t mask, any;
    uint32_t instance; /* the best hit's, BVH_INVALID until one is taken */
    bvh_hit hit;       /* its hit in the bottom-level tree (t is world t) */
    bvh__best at;      /* its packet and lane (pk NULL: a tree without the wide layout) */
} bvh__scene_ctx;
/* The top level's leaf step: instance `inst` skipped by mask, else the ray in its space and the
   bottom-level tree traced there: its 8-wide layout (where it has one) for the same ISA, on the
   world ray's own set-up (rx, q) where the instance's transform is the identity (kind
   BVH__TOP_IDENTITY: the transform would give back the same ray). */
BVH__INLINE int bvh__instance_step(void *arg, bvh_ray *ray, bvh__rayx *rx, const bvh__ray8 *q, uint32_t inst,
                                   uint32_t kind, int isa) {
    bvh__scene_ctx *c = BVH__CAST(bvh__scene_ctx *, arg);
    const bvh_instance *in = &c->scene->instances[inst];
    const bvh_tree *t = in->tree;
    const float *inv = c->scene->inverse + 12 * (size_t)inst;
    bvh_ray local;
    bvh_hit h;
    bvh__best at;
    if (!(in->mask & c->mask)) return 0;
    at.pk = NULL; /* a hit without a packet: the normal from tree.tris */
    if (!in->custom && t->nodes8 && t->tris) {
        const bvh_ray *r = NULL; /* NULL: the world ray's set-up */
        if (kind != BVH__TOP_IDENTITY) {
            local = bvh__ray_transform(ray, inv);
            r = &local;
        }
        if (c->any) return bvh__trace8_isa(t, r, rx, q, ray->tmax, NULL, NULL, 1, isa);
        /* the packet keeps the hit's vertices for the normal */
        if (!bvh__trace8_isa(t, r, rx, q, ray->tmax, &h, &at, 0, isa)) return 0;
    } else {
        local = bvh__ray_transform(ray, inv);
        if (c->any) return in->custom ? bvh_occluded_custom(t, &local, in->custom) : bvh_occluded(t, &local);
        if (in->custom ? !bvh_intersect_custom(t, &local, &h, in->custom) : !bvh_intersect(t, &local, &h)) return 0;
    }
    if (h.t == ray->tmax && inst > c->instance) return 0; /* ties: the lowest instance */
    c->instance = inst;
    c->hit = h;
    c->at = at;
    ray->tmax = h.t;
    return 1;
}
/* The top level's 8-wide traversal with the instance step, compiled for each ISA. */
BVH__INLINE int bvh__scene_top8(const bvh_scene *scene, const bvh_ray *ray, bvh__scene_ctx *c, int any, int isa) {
    bvh__rayx rx;
    bvh__ray8 q;
    bvh_ray w = *ray;
    if (!bvh__ray8_setup(ray, &rx, &q, isa)) return 0;
    return bvh__traverse8_body(scene->top8, NULL, &rx, &q, 0.0f, ray->tmax, NULL, NULL, any, isa, bvh__instance_step, c,
                               &w);
}
/* The world normal of the best hit: M^-T times the object-space normal (v1 - v0) x (v2 - v0), in
   double, normalised. The vertices come from the hit's packet, which the traversal has just read
   (the same floats as tree.tris), rather than from tree.tris through the primitive's reference:
   two cache misses a hit. Scalars, not arrays and loops: the compiler keeps them in registers
   (arrays it stored and reloaded, value by value, on a scene ray's path). Inlined, so that it is
   compiled with each ISA's scene function: called from the AVX2 one, it cost a hit more. */
BVH__INLINE bvh_vec3 bvh__scene_normal(const bvh_scene *scene, const bvh__scene_ctx *c) {
    const float *m = scene->inverse + 12 * (size_t)c->instance;
    double ax, ay, az, bx, by, bz, cx, cy, cz, nx, ny, nz, wx, wy, wz, l;
    bvh_vec3 out = {0.0f, 0.0f, 0.0f};
    if (c->at.pk) {
        const bvh_tri4 *p = c->at.pk;
        const uint32_t i = c->at.lane;
        ax = p->v[0][0][i];
        ay = p->v[0][1][i];
        az = p->v[0][2][i];
        bx = p->v[1][0][i];
        by = p->v[1][1][i];
        bz = p->v[1][2][i];
        cx = p->v[2][0][i];
        cy = p->v[2][1][i];
        cz = p->v[2][2][i];
    } else {
        const bvh_tree *tree = scene->instances[c->instance].tree;
        const float *t;
        if (!tree->tris) return out; /* a custom primitive: the caller's normal */
        t = tree->tris + 9 * (size_t)scene->ref_of_prim[scene->ref_base[scene->mesh[c->instance]] + c->hit.prim];
        ax = t[0];
        ay = t[1];
        az = t[2];
        bx = t[3];
        by = t[4];
        bz = t[5];
        cx = t[6];
        cy = t[7];
        cz = t[8];
    }
    bx -= ax; /* the edges, exact: a difference of two floats fits in a double */
    by -= ay;
    bz -= az;
    cx -= ax;
    cy -= ay;
    cz -= az;
    nx = by * cz - bz * cy;
    ny = bz * cx - bx * cz;
    nz = bx * cy - by * cx;
    /* M^-T even for the identity, which can turn a -0 into +0: the same bits as before and as
       the path tracer's Embree side, which a normal's sign of zero steers */
    wx = m[0] * nx + m[4] * ny + m[8] * nz;
    wy = m[1] * nx + m[5] * ny + m[9] * nz;
    wz = m[2] * nx + m[6] * ny + m[10] * nz;
    l = sqrt(wx * wx + wy * wy + wz * wz);
    if (!(l > 0.0)) return out;
    out.x = (float)(wx / l); /* divisions, not products with 1 / l: the same bits as before */
    out.y = (float)(wy / l);
    out.z = (float)(wz / l);
    return out;
}
/* A scene ray from the checks to the hit record, compiled once for each ISA and kind (isa and any
   constants), so that a ray pays one call before the top level's loop. */
BVH__INLINE int bvh__scene_trace_at(const bvh_scene *scene, const bvh_ray *ray, uint32_t mask, bvh_scene_hit *hit,
                                    int any, int isa) {
    bvh__scene_ctx c;
    int found = 0;
    c.scene = scene;
    c.mask = mask;
    c.any = (uint32_t)any;
    c.instance = BVH_INVALID;
    c.hit.t = c.hit.u = c.hit.v = 0.0f; /* read only after a hit set them; some compilers cannot tell */
    c.hit.prim = BVH_INVALID;
    c.at.pk = NULL;
    if (scene && ray && mask && scene->top8_count) found = bvh__scene_top8(scene, ray, &c, any, isa);
    if (!hit) return found;
    if (!found) {
        hit->t = ray ? ray->tmax : BVH_INF;
        hit->u = hit->v = 0.0f;
        hit->instance = hit->id = hit->prim = BVH_INVALID;
        hit->normal.x = hit->normal.y = hit->normal.z = 0.0f;
        return 0;
    }
    hit->t = c.hit.t;
    hit->u = c.hit.u;
    hit->v = c.hit.v;
    hit->instance = c.instance;
    hit->id = scene->instances[c.instance].id;
    hit->prim = c.hit.prim;
    hit->normal = bvh__scene_normal(scene, &c);
    return 1;
}
#ifdef BVH__AVX2
__attribute__((target("avx2,fma,popcnt"))) static int bvh__scene_closest_avx2(const bvh_scene *s, const bvh_ray *r,
                                                                              uint32_t mask, bvh_scene_hit *hit) {
    return bvh__scene_trace_at(s, r, mask, hit, 0, 1);
}
__attribute__((target("avx2,fma,popcnt"))) static int bvh__scene_any_avx2(const bvh_scene *s, const bvh_ray *r,
                                                                          uint32_t mask) {
    return bvh__scene_trace_at(s, r, mask, NULL, 1, 1);
}
#endif
static int bvh__scene_closest_base(const bvh_scene *s, const bvh_ray *r, uint32_t mask, bvh_scene_hit *hit) {
    return bvh__scene_trace_at(s, r, mask, hit, 0, 0);
}
static int bvh__scene_any_base(const bvh_scene *s, const bvh_ray *r, uint32_t mask) {
    return bvh__scene_trace_at(s, r, mask, NULL, 1, 0);
}
/* isa: bvh__have_avx2()'s answer, asked by the caller (once a batch range). hit NULL: any hit. */
static int bvh__scene_trace(const bvh_scene *scene, const bvh_ray *ray, uint32_t mask, bvh_scene_hit *hit, int isa) {
#ifdef BVH__AVX2
    if (isa) return hit ? bvh__scene_closest_avx2(scene, ray, mask, hit) : bvh__scene_any_avx2(scene, ray, mask);
#endif
    (void)isa; /* without BVH__AVX2: always 0 */
    return hit ? bvh__scene_closest_base(scene, ray, mask, hit) : bvh__scene_any_base(scene, ray, mask);
}
BVH_API int bvh_scene_intersect(const bvh_scene *scene, const bvh_ray *ray, uint32_t mask, bvh_scene_hit *hit) {
    return bvh__scene_trace(scene, ray, mask, hit, bvh__have_avx2());
}
BVH_API int bvh_scene_occluded(const bvh_scene *scene, const bvh_ray *ray, uint32_t mask) {
    return bvh__scene_trace(scene, ray, mask, NULL, bvh__have_avx2());
}
/* The scene's batch calls: bvh__batch_go with the scene's rays (see bvh__batch_range). */
static bvh_result bvh__scene_batch(const bvh_scene *scene, const bvh_ray *rays, uint32_t mask, bvh_scene_hit *hits,
                                   uint8_t *occluded, size_t count, const bvh_batch_desc *desc) {
    bvh__batch b;
    if (!scene || (count && (!rays || (!hits && !occluded)))) return BVH_ERROR_INVALID_ARGUMENT;
    if (!bvh__allocator_paired(&scene->allocator)) return BVH_ERROR_INVALID_ARGUMENT;
    bvh__batch_init(&b, rays, occluded, count);
    b.scene = scene;
    b.mask = mask;
    b.scene_hits = hits;
    return bvh__batch_go(&b, &scene->allocator, desc ? desc->threads : 0, desc ? &desc->pool : NULL);
}
BVH_API bvh_result bvh_scene_intersect_batch(const bvh_scene *scene, const bvh_ray *rays, uint32_t mask,
                                             bvh_scene_hit *hits, size_t count, const bvh_batch_desc *desc) {
    return bvh__scene_batch(scene, rays, mask, hits, NULL, count, desc);
}
BVH_API bvh_result bvh_scene_occluded_batch(const bvh_scene *scene, const bvh_ray *rays, uint32_t mask,
                                            uint8_t *occluded, size_t count, const bvh_batch_desc *desc) {
    return bvh__scene_batch(scene, rays, mask, NULL, occluded, count, desc);
}

/* ============================================================================================ */
/* == refit ===================================================================================== */
/* The topology stays; the boxes follow the primitives. With the 8-wide layout, one pass over it
   does everything: wide subtrees taken in parallel, each in post-order from its head (the few wide
   nodes above the heads last, on one thread); at each wide node, its grouping (bvh_node8.head,
   .shape) gives the binary subtrees of its leaf slots, whose triangles are fetched (all of the
   node's first, asked ahead), written to tree.tris and to the packets, and boxed bottom-up, then
   the binary nodes opened in it, then its slot boxes. Without it (trace_width 2, box trees):
   the triangle copy in reference order, then binary subtrees in parallel. Every box is a min/max
   of the same inputs, so the result does not depend on the thread count or the order. */
/* ============================================================================================ */
#define BVH__REFIT_HEADS 256u /* subtrees the threads share (a PLOC tree's vary a lot in size) */
typedef struct bvh__refit {
    bvh_tree *tree;
    const bvh_triangles *tris; /* the new triangles, or */
    const bvh_aabb *boxes;     /* the new boxes */
    uint32_t heads[BVH__REFIT_HEADS], top[BVH__REFIT_HEADS], nheads, ntop;
    uint32_t next;                  /* the 8-wide pass: the next head to take */
    uint32_t bad[BVH__MAX_THREADS]; /* per thread: the precheck's failures; the walk's broken nodes */
} bvh__refit;

/* Node b from its children (interior) or its primitives (leaf); 0 if the tree is broken there. */
BVH__INLINE int bvh__refit_node(const bvh__refit *j, uint32_t b) {
    bvh_tree *t = j->tree;
    bvh_node *n = &t->nodes[b];
    bvh_aabb box = bvh__empty();
    uint32_t k;
    if (n->count) {
        if (n->index > t->ref_count || n->count > t->ref_count - n->index) return 0;
        for (k = n->index; k < n->index + n->count; k++) {
            uint32_t p = t->prims[k];
            if (p >= t->prim_count) return 0;
            if (j->tris) {
                box = bvh__merge(box, bvh__tri_box(t->tris + 9 * (size_t)k)); /* bvh__refit_tris_fn's */
            } else {
                box = bvh__merge(box, j->boxes[p]);
            }
        }
    } else {
        box = bvh__merge(bvh__node_box(&t->nodes[n->index]), bvh__node_box(&t->nodes[n->index + 1]));
    }
    bvh__set_box(n, box);
    return 1;
}
/* The subtree of head h in post-order (children before their parent). Child indices must lie
   after their parent and inside the array, so every path ends; 0 if the tree is broken. */
static int bvh__refit_subtree(const bvh__refit *j, uint32_t h) {
    uint32_t node[2 * BVH_MAX_DEPTH + 4], sp = 0;
    uint8_t open[2 * BVH_MAX_DEPTH + 4];
    const bvh_node *nodes = j->tree->nodes;
    node[sp] = h;
    open[sp++] = 0;
    while (sp) {
        uint32_t b = node[sp - 1];
        const bvh_node *n = &nodes[b];
        if (n->count || open[sp - 1]) {
            if (!bvh__refit_node(j, b)) return 0;
            sp--;
            continue;
        }
        if (n->index <= b || n->index >= j->tree->node_count - 1 || sp + 2 > 2 * BVH_MAX_DEPTH + 4) return 0;
        open[sp - 1] = 1;
        node[sp] = n->index + 1;
        open[sp++] = 0;
        node[sp] = n->index;
        open[sp++] = 0;
    }
    return 1;
}
/* The new triangles into tree.tris, in reference order; the references are in tree order, the
   triangles in the caller's: as bvh__back_fn, ask ahead for the indices of the 16th triangle on
   and for the vertices of the 8th (a 1M-triangle refit spent most of its time waiting for them). */
static void bvh__refit_tris_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    bvh__refit *j = BVH__CAST(bvh__refit *, arg);
    const bvh_triangles *t = j->tris;
    const uint32_t *prims = j->tree->prims, n = j->tree->prim_count;
    uint32_t bad = 0;
    size_t b, e, i;
    (void)team;
    bvh__range(j->tree->ref_count, tid, nt, &b, &e);
    for (i = b; i < e; i++) {
        if (i + 16 < e && prims[i + 16] < n) {
            uint32_t id = prims[i + 16];
            if (t->indices) {
                BVH__PREFETCH(&t->indices[3 * (size_t)id]);
            } else {
                BVH__PREFETCH(bvh__vertex(t, 3 * id));
                BVH__PREFETCH(bvh__vertex(t, 3 * id + 2));
            }
        }
        if (t->indices && i + 8 < e && prims[i + 8] < n) {
            const uint32_t *ix = &t->indices[3 * (size_t)prims[i + 8]];
            BVH__PREFETCH(bvh__vertex(t, ix[0]));
            BVH__PREFETCH(bvh__vertex(t, ix[1]));
            BVH__PREFETCH(bvh__vertex(t, ix[2]));
        }
        if (prims[i] < n)
            bvh__fetch_triangle(t, prims[i], j->tree->tris + 9 * i);
        else
            bad++;
    }
    j->bad[tid] += bad;
}
static void bvh__refit_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    bvh__refit *j = BVH__CAST(bvh__refit *, arg);
    uint32_t i;
    (void)team;
    for (i = tid; i < j->nheads; i += nt)
        if (!bvh__refit_subtree(j, j->heads[i])) j->bad[tid]++;
}
/* The heads: from the root, each interior head is replaced by its two children, round after
   round, until there are BVH__REFIT_HEADS or only leaves. The replaced nodes (top[], in the order
   replaced: parents before children) are refitted after the heads, last to first. */
static int bvh__refit_heads(bvh__refit *j) {
    const bvh_node *nodes = j->tree->nodes;
    uint32_t i = 0, grew = 0;
    j->heads[0] = 0;
    j->nheads = 1;
    j->ntop = 0;
    while (j->nheads < BVH__REFIT_HEADS) {
        uint32_t b = j->heads[i];
        if (!nodes[b].count) {
            if (nodes[b].index <= b || nodes[b].index >= j->tree->node_count - 1) return 0;
            j->top[j->ntop++] = b;
            j->heads[i] = nodes[b].index;
            j->heads[j->nheads++] = nodes[b].index + 1;
            grew = 1;
        }
        if (++i == j->nheads) { /* a round done */
            if (!grew) break;
            i = grew = 0;
        }
    }
    return 1;
}

/* The 8-wide pass. Node w once its wide children are done: 0 if the tree is broken there. */
#define BVH__WREFS (BVH__W * BVH__MAX_LEAF) /* references of a wide node's leaf slots, at most */
typedef struct bvh__wnode_scratch {
    uint32_t pre[BVH__W * (2 * BVH__SLOT_REFS)]; /* the leaf slots' binary nodes, pre-order */
    uint32_t refs[BVH__WREFS];                   /* their references, in packet order */
    uint32_t pre_end[BVH__W], ref_end[BVH__W];
    uint32_t ahead, ahead_ix;     /* bvh_refit: references whose vertices (indices) were asked for */
    float tri[9 * BVH__MAX_LEAF]; /* bvh_refit: a leaf slot's triangles ... */
    uint32_t prim[BVH__MAX_LEAF]; /* ... and primitives (bvh__refit_gather) */
} bvh__wnode_scratch;
/* The binary subtree of leaf slot b: its nodes in pre-order (left first) appended to pre[] and
   its references to refs[] (the packets' order); 0 if it is not a leaf slot of at most
   BVH__SLOT_REFS references (or a leaf of at most BVH__MAX_LEAF), or out of range. */
static int bvh__slot_walk(const bvh_tree *t, uint32_t b, uint32_t *pre, uint32_t *npre, uint32_t *refs,
                          uint32_t *nref) {
    uint32_t stack[2 * BVH__SLOT_REFS + 2], sp = 0, first = *nref, k, cap;
    const bvh_node *root = &t->nodes[b];
    cap = root->count ? BVH__MAX_LEAF : BVH__SLOT_REFS;
    stack[sp++] = b;
    while (sp) {
        uint32_t x = stack[--sp];
        const bvh_node *n = &t->nodes[x];
        if (*npre >= BVH__W * (2 * BVH__SLOT_REFS)) return 0;
        pre[(*npre)++] = x;
        if (n->count) {
            if (n->index > t->ref_count || n->count > t->ref_count - n->index || n->count > cap - (*nref - first))
                return 0;
            for (k = 0; k < n->count; k++) refs[(*nref)++] = n->index + k;
        } else {
            if (n->index <= x || n->index >= t->node_count - 1 || sp + 2 > 2 * BVH__SLOT_REFS + 2) return 0;
            stack[sp++] = n->index + 1;
            stack[sp++] = n->index;
        }
    }
    return 1;
}
/* The box of n consecutive triangles (a leaf's, in tree.tris). */
static bvh_aabb bvh__tris_box(const float *t, uint32_t n) {
    bvh_aabb b;
#ifdef BVH__SSE
    __m128 lo = _mm_set1_ps(BVH_INF), hi = _mm_set1_ps(-BVH_INF);
    float l[4], h[4];
    uint32_t i;
    for (i = 0; i < n; i++, t += 9) { /* lane 3 is not read back */
        __m128 a = _mm_loadu_ps(t), c = _mm_loadu_ps(t + 3);
        __m128 e =
            _mm_movelh_ps(_mm_loadl_pi(_mm_setzero_ps(), BVH__CAST(const __m64 *, BVH__CAST(const void *, t + 6))),
                          _mm_load_ss(t + 8));
        lo = _mm_min_ps(lo, _mm_min_ps(_mm_min_ps(a, c), e));
        hi = _mm_max_ps(hi, _mm_max_ps(_mm_max_ps(a, c), e));
    }
    _mm_storeu_ps(l, lo);
    _mm_storeu_ps(h, hi);
    b.min.x = l[0];
    b.min.y = l[1];
    b.min.z = l[2];
    b.max.x = h[0];
    b.max.y = h[1];
    b.max.z = h[2];
#else
    uint32_t i;
    b = bvh__empty();
    for (i = 0; i < n; i++) b = bvh__merge(b, bvh__tri_box(t + 9 * (size_t)i));
#endif
    return b;
}
/* The triangles of the references after hi, the highest of the wide node being refitted, asked
   for BVH__REFIT_AHEAD references ahead (their indices twice as far): a walk's wide nodes take
   the references nearly in order, and their vertices, in the caller's order, lie anywhere, so
   that asking for them only in their own node left each node waiting on them. */
#define BVH__REFIT_AHEAD 256u
static void bvh__refit_ask_refs(const bvh_tree *t, const bvh_triangles *tr, uint32_t hi, bvh__wnode_scratch *sc) {
    uint32_t r, e;
    if (tr->indices) {
        e = t->ref_count - hi > 2u * BVH__REFIT_AHEAD ? hi + 2u * BVH__REFIT_AHEAD : t->ref_count;
        for (r = sc->ahead_ix > hi ? sc->ahead_ix : hi + 1u; r < e; r++)
            if (t->prims[r] < t->prim_count) BVH__PREFETCH(&tr->indices[3 * (size_t)t->prims[r]]);
        sc->ahead_ix = e;
    }
    e = t->ref_count - hi > BVH__REFIT_AHEAD ? hi + BVH__REFIT_AHEAD : t->ref_count;
    for (r = sc->ahead > hi ? sc->ahead : hi + 1u; r < e; r++) {
        const uint32_t p = t->prims[r];
        if (p >= t->prim_count) continue; /* refused where its node is refitted */
        if (tr->indices) {
            const uint32_t *ix = &tr->indices[3 * (size_t)p];
            if (ix[0] < tr->vertex_count) BVH__PREFETCH(bvh__vertex(tr, ix[0]));
        } else {
            BVH__PREFETCH(bvh__vertex(tr, 3 * p));
            BVH__PREFETCH((const char *)(const void *)bvh__vertex(tr, 3 * p) + 32);
        }
    }
    sc->ahead = e;
}
/* A leaf slot's m triangles (tree positions refs[]) from the caller's buffers into sc->tri, their
   primitives into sc->prim: what its boxes and packets are made from, in this thread's caches. */
static void bvh__refit_gather(const bvh_triangles *tr, const uint32_t *prims, const uint32_t *refs, uint32_t m,
                              bvh__wnode_scratch *sc) {
    uint32_t k;
    for (k = 0; k < m; k++) sc->prim[k] = prims[refs[k]];
    if (!tr->indices && (tr->stride == 0 || tr->stride == 3 * sizeof(float))) { /* a packed soup */
        const char *v = BVH__CAST(const char *, BVH__CAST(const void *, tr->positions));
        for (k = 0; k < m; k++) memcpy(sc->tri + 9 * (size_t)k, v + 36 * (size_t)sc->prim[k], 36);
    } else {
        for (k = 0; k < m; k++) bvh__fetch_triangle(tr, sc->prim[k], sc->tri + 9 * (size_t)k);
    }
}
/* nf floats from src to d, streamed past the caches (bvh__packets_write says why; the caller's
   team pass fences them): 16-byte stores where d is aligned so, 4-byte ones at the ends. */
static void bvh__stream_floats(float *d, const float *src, size_t nf) {
#ifdef BVH__SSE
    size_t f = 0;
    int bits;
    for (; f < nf && ((uintptr_t)(void *)(d + f) & 15u); f++) { /* floats are 4-aligned */
        memcpy(&bits, src + f, 4);
        _mm_stream_si32(BVH__CAST(int *, BVH__CAST(void *, d + f)), bits);
    }
    for (; f + 4 <= nf; f += 4) _mm_stream_ps(d + f, _mm_loadu_ps(src + f));
    for (; f < nf; f++) {
        memcpy(&bits, src + f, 4);
        _mm_stream_si32(BVH__CAST(int *, BVH__CAST(void *, d + f)), bits);
    }
#else
    memcpy(d, src, nf * sizeof(float));
#endif
}
/* The slot's triangles into tree.tris: streamed where their positions run on (as a builder lays
   them out), else stored one by one. */
static void bvh__refit_tris_out(float *tris, const uint32_t *refs, uint32_t m, const float *src) {
    uint32_t k;
    for (k = 1; k < m && refs[k] == refs[0] + k; k++) {
    }
    if (k == m) {
        bvh__stream_floats(tris + 9 * (size_t)refs[0], src, 9 * (size_t)m);
        return;
    }
    for (k = 0; k < m; k++) memcpy(tris + 9 * (size_t)refs[k], src + 9 * (size_t)k, 36);
}
static int bvh__refit_wnode(const bvh__refit *j, uint32_t w, bvh__wnode_scratch *sc) {
    bvh_tree *t = j->tree;
    bvh_node8 *n = &t->nodes8[w];
    const bvh_triangles *tr = j->tris;
    bvh__group g;
    uint32_t i, k, npre = 0, nref = 0, hi = 0;
    if (!bvh__group_read(t->nodes, t->node_count, n, &g)) return 0;
    for (i = 0; i < BVH__W; i++) { /* the leaf slots' subtrees, their triangles asked ahead */
        uint32_t r0 = nref;
        if (i >= g.nslot) {
            if (n->count[i] || n->child[i]) return 0;
        } else if (n->count[i]) {
            if (!bvh__slot_walk(t, g.slot[i], sc->pre, &npre, sc->refs, &nref)) return 0;
            if (n->count[i] != (nref - r0 + BVH__PACKET - 1) / BVH__PACKET || n->child[i] > t->tri4_count ||
                n->count[i] > t->tri4_count - n->child[i])
                return 0;
            for (k = r0; k < nref; k++) {
                uint32_t p = t->prims[sc->refs[k]];
                if (sc->refs[k] > hi) hi = sc->refs[k];
                if (p >= t->prim_count) return 0;
                if (tr->indices)
                    BVH__PREFETCH(&tr->indices[3 * (size_t)p]);
                else
                    BVH__PREFETCH(bvh__vertex(tr, 3 * p));
            }
        } else if (n->child[i] <= w || n->child[i] >= t->node8_count || t->nodes8[n->child[i]].head != g.slot[i]) {
            return 0;
        }
        sc->pre_end[i] = npre;
        sc->ref_end[i] = nref;
    }
    if (nref) bvh__refit_ask_refs(t, tr, hi, sc);
    if (tr->indices)
        for (k = 0; k < nref; k++) { /* the indices have arrived by now, mostly */
            const uint32_t *ix = &tr->indices[3 * (size_t)t->prims[sc->refs[k]]];
            BVH__PREFETCH(bvh__vertex(tr, ix[0]));
            BVH__PREFETCH(bvh__vertex(tr, ix[1]));
            BVH__PREFETCH(bvh__vertex(tr, ix[2]));
        }
    for (i = 0; i < g.nslot; i++) { /* each leaf slot from its triangles gathered in sc->tri */
        const uint32_t r0 = i ? sc->ref_end[i - 1] : 0, m = sc->ref_end[i] - r0, *refs = sc->refs + r0;
        uint32_t off = m;
        if (!n->count[i]) continue;
        if (m > BVH__MAX_LEAF) return 0; /* a slot is one leaf, or a subtree of BVH__SLOT_REFS at most */
        bvh__refit_gather(tr, t->prims, refs, m, sc);
        for (k = sc->pre_end[i]; k-- > (i ? sc->pre_end[i - 1] : 0);) { /* children before parents */
            bvh_node *x = &t->nodes[sc->pre[k]];
            if (x->count) { /* its references are the slot's last ones not yet taken (pre-order) */
                off -= x->count;
                bvh__set_box(x, bvh__tris_box(sc->tri + 9 * (size_t)off, x->count));
            } else {
                bvh__set_box(x, bvh__merge(bvh__node_box(&t->nodes[x->index]), bvh__node_box(&t->nodes[x->index + 1])));
            }
        }
        bvh__packets_write(NULL, m, sc->prim, sc->tri, t->tri4 + n->child[i]);
        bvh__refit_tris_out(t->tris, refs, m, sc->tri);
    }
    for (k = g.nopen; k-- > 0;) bvh__refit_node(j, g.open[k]); /* interior: cannot fail */
    /* the slot boxes in one streamed write of the node's three box lines, which nothing here reads
       (an ordinary store would read them from memory first); empty slots as built */
    {
        float box[6 * BVH__W]; /* bvh_node8's min[3][8] and max[3][8], in that order */
        for (i = 0; i < BVH__W; i++) {
            const bvh_node *x = i < g.nslot ? &t->nodes[g.slot[i]] : NULL;
            box[i] = x ? x->min.x : BVH_INF;
            box[BVH__W + i] = x ? x->min.y : BVH_INF;
            box[2 * BVH__W + i] = x ? x->min.z : BVH_INF;
            box[3 * BVH__W + i] = x ? x->max.x : -BVH_INF;
            box[4 * BVH__W + i] = x ? x->max.y : -BVH_INF;
            box[5 * BVH__W + i] = x ? x->max.z : -BVH_INF;
        }
        bvh__stream_floats(&n->min[0][0], box, 3 * BVH__W);
        bvh__stream_floats(&n->max[0][0], box + 3 * BVH__W, 3 * BVH__W);
    }
    return 1;
}
/* Asks for what wide node w will read, `ahead` nodes before it is taken (out of range: nothing),
   in stages that each read only lines the stage before asked for: 3, its line with the head; 2,
   the head's binary node; 1, the block of the head's descendants (depth-first: its grouping's
   binary nodes and its leaf slots' subtrees lie there, before those of its wide children), as
   many lines as its references can need, at most 48. The grouping walk that follows missed
   at almost every binary node without it (docs/bench, 0.9.1). Only prefetches: it must stay
   inlined (see BVH__PREFETCH). */
BVH__INLINE void bvh__refit_ask(const bvh_tree *t, uint32_t w, int ahead) {
    const bvh_node8 *n;
    if (w >= t->node8_count) return;
    n = &t->nodes8[w];
    if (ahead == 3) {
        BVH__PREFETCH(&n->head);
    } else if (n->head < t->node_count) {
        const bvh_node *b = &t->nodes[n->head];
        if (ahead == 2) {
            BVH__PREFETCH(b);
        } else if (!b->count && b->index < t->node_count) {
            uint32_t k, refs = 0, lines;
            const char *p = (const char *)(const void *)&t->nodes[b->index];
            for (k = 0; k < BVH__W; k++) refs += n->count[k];
            lines = refs * 4u; /* packets x 4 references x 2 nodes x 32 bytes / 64 */
            if (lines > 48u) lines = 48u;
            if (lines > (t->node_count - b->index) / 2u) lines = (t->node_count - b->index) / 2u;
            for (k = 0; k < lines; k++) BVH__PREFETCH(p + 64 * (size_t)k);
        }
    }
}
/* bvh__refit_ask for the wide nodes taken three, two and one steps from now (each stage a step
   further for the node that comes sooner); BVH_INVALID: none. */
BVH__INLINE void bvh__refit_ask_next(const bvh_tree *t, uint32_t in3, uint32_t in2, uint32_t in1) {
    bvh__refit_ask(t, in3, 3);
    bvh__refit_ask(t, in2, 2);
    bvh__refit_ask(t, in1, 1);
}
/* Wide node n's slots in the order of their binary nodes (bvh_node8.order read back: the slots are
   stored in any-hit order), each slot once whatever order holds (a damaged one is refused
   later, by bvh__group_read). The references and the binary nodes lie in that order, so a walk
   that takes the children so reads them nearly in order (slot order jumps about in them). */
static void bvh__slots_by_head(const bvh_node8 *n, uint32_t by[BVH__W]) {
    uint32_t i, s, nb = 0, seen = 0, any = 0;
    for (i = 0; i < BVH__W; i++) any |= n->order[i];
    for (i = 0; i < BVH__W; i++) { /* all zero: slot i (files of 0.9.3 and before) */
        s = any ? n->order[i] : i;
        if (s < BVH__W && !((seen >> s) & 1u)) {
            seen |= 1u << s;
            by[nb++] = s;
        }
    }
    for (s = 0; nb < BVH__W; s++)
        if (!((seen >> s) & 1u)) by[nb++] = s;
}
/* The wide subtree of head h in post-order, each node's children in the binary tree's order; 0 if
   the tree is broken (child indices must point forward: no cycle). */
static int bvh__refit_wsubtree(const bvh__refit *j, uint32_t h, bvh__wnode_scratch *sc) {
    uint32_t stack[BVH__W * (BVH_MAX_DEPTH + 2)], sp = 0, by[BVH__W]; /* w << 1 | children pushed */
    const bvh_tree *t = j->tree;
    stack[sp++] = h << 1;
    while (sp) {
        uint32_t e = stack[sp - 1], w = e >> 1, i;
        const bvh_node8 *n = &t->nodes8[w];
        if (e & 1u) {
            sp--;
            /* the next entries, most of them taken next (a wide leaf's parent pushes its children
               at once), asked for a stage further each step down the stack */
            bvh__refit_ask_next(t, sp >= 3 ? stack[sp - 3] >> 1 : BVH_INVALID,
                                sp >= 2 ? stack[sp - 2] >> 1 : BVH_INVALID, sp >= 1 ? stack[sp - 1] >> 1 : BVH_INVALID);
            if (!bvh__refit_wnode(j, w, sc)) return 0;
            continue;
        }
        stack[sp - 1] |= 1u;
        bvh__slots_by_head(n, by);
        for (i = BVH__W; i-- > 0;) /* pushed last to first: taken in the binary tree's order */
            if (!n->count[by[i]] && n->child[by[i]]) {
                const uint32_t c = n->child[by[i]];
                if (c <= w || c >= t->node8_count || sp == BVH__W * (BVH_MAX_DEPTH + 2)) return 0;
                stack[sp++] = c << 1;
            }
    }
    return 1;
}
/* The heads taken one at a time by whichever thread is free (their subtrees vary a lot in size; a
   fixed share left one thread waiting for the other); without atomics, every nt-th. Each box is
   the same whoever computes it. */
static void bvh__refit_wide_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    bvh__refit *j = BVH__CAST(bvh__refit *, arg);
    bvh__wnode_scratch sc; /* 20 KiB of this thread's stack */
    uint32_t i;
    (void)team;
    sc.ahead = sc.ahead_ix = 0;
#if defined(__GNUC__) || defined(__clang__)
    (void)nt;
    while ((i = __atomic_fetch_add(&j->next, 1u, __ATOMIC_RELAXED)) < j->nheads)
        if (!bvh__refit_wsubtree(j, j->heads[i], &sc)) j->bad[tid]++;
#else
    for (i = tid; i < j->nheads; i += nt)
        if (!bvh__refit_wsubtree(j, j->heads[i], &sc)) j->bad[tid]++;
#endif
}
/* The wide heads: from the root, each head with wide children is replaced by them, round after
   round, until there are BVH__REFIT_HEADS / 4 or more (or no more can be opened). The replaced
   nodes (top[], parents before children) are refitted after the heads, last to first. */
static int bvh__refit_wheads(bvh__refit *j) {
    const bvh_tree *t = j->tree;
    uint32_t i = 0, grew = 0;
    j->heads[0] = 0;
    j->nheads = 1;
    j->ntop = 0;
    while (j->nheads < BVH__REFIT_HEADS / 4 && j->ntop < BVH__REFIT_HEADS) {
        uint32_t w = j->heads[i], c = 0, s;
        const bvh_node8 *n = &t->nodes8[w];
        for (s = 0; s < BVH__W; s++) c += !n->count[s] && n->child[s];
        if (c && j->nheads - 1 + c <= BVH__REFIT_HEADS) {
            uint32_t first = 1;
            j->top[j->ntop++] = w;
            for (s = 0; s < BVH__W; s++)
                if (!n->count[s] && n->child[s]) {
                    if (n->child[s] <= w || n->child[s] >= t->node8_count) return 0;
                    if (first)
                        j->heads[i] = n->child[s];
                    else
                        j->heads[j->nheads++] = n->child[s];
                    first = 0;
                }
            grew = 1;
        }
        if (++i == j->nheads) { /* a round done */
            if (!grew) break;
            i = grew = 0;
        }
    }
    return 1;
}

/* Whether any of n floats at p (any alignment) is Inf or NaN, by their bits without branches:
   without its sign, such a float's bits are above 0x7f7fffff (SSE2: 16 floats a step; AVX2: 32,
   the largest such bits kept per lane, one compare at the end). */
#ifdef BVH__AVX2
__attribute__((target("avx2"))) static int bvh__any_nonfinite32(const char *p, size_t steps) {
    const __m256i sign = _mm256_set1_epi32(0x7fffffff);
    __m256i a = _mm256_setzero_si256(), b = _mm256_setzero_si256();
    size_t i;
    for (i = 0; i < steps; i++, p += 32 * sizeof(float)) {
        const __m256i *q = BVH__CAST(const __m256i *, BVH__CAST(const void *, p));
        a = _mm256_max_epu32(a, _mm256_max_epu32(_mm256_and_si256(_mm256_loadu_si256(q), sign),
                                                 _mm256_and_si256(_mm256_loadu_si256(q + 1), sign)));
        b = _mm256_max_epu32(b, _mm256_max_epu32(_mm256_and_si256(_mm256_loadu_si256(q + 2), sign),
                                                 _mm256_and_si256(_mm256_loadu_si256(q + 3), sign)));
    }
    return _mm256_movemask_epi8(_mm256_cmpgt_epi32(_mm256_max_epu32(a, b), _mm256_set1_epi32(0x7f7fffff))) != 0;
}
#endif
static int bvh__any_nonfinite(const void *data, size_t n) {
    const char *p = BVH__CAST(const char *, data);
    size_t f = 0;
    uint32_t w, bad = 0;
#ifdef BVH__AVX2
    if (n >= 64 && bvh__have_avx2()) {
        bad = (uint32_t)bvh__any_nonfinite32(p, n / 32);
        f = n / 32 * 32;
    }
#endif
#ifdef BVH__SSE
    {
        const __m128i sign = _mm_set1_epi32(0x7fffffff), big = _mm_set1_epi32(0x7f7fffff);
        __m128i acc = _mm_setzero_si128();
        for (; f + 16 <= n; f += 16) {
            const __m128i *q = BVH__CAST(const __m128i *, BVH__CAST(const void *, p + f * sizeof(float)));
            __m128i a = _mm_and_si128(_mm_loadu_si128(q), sign), b = _mm_and_si128(_mm_loadu_si128(q + 1), sign);
            __m128i c = _mm_and_si128(_mm_loadu_si128(q + 2), sign), d = _mm_and_si128(_mm_loadu_si128(q + 3), sign);
            acc = _mm_or_si128(acc, _mm_or_si128(_mm_or_si128(_mm_cmpgt_epi32(a, big), _mm_cmpgt_epi32(b, big)),
                                                 _mm_or_si128(_mm_cmpgt_epi32(c, big), _mm_cmpgt_epi32(d, big))));
        }
        bad |= _mm_movemask_epi8(acc) != 0;
    }
#endif
    for (; f < n; f++) {
        memcpy(&w, p + f * sizeof(float), sizeof w);
        bad |= (w & 0x7fffffffu) > 0x7f7fffffu;
    }
    return bad != 0;
}
/* The precheck, before anything changes: indices in range, and every vertex (every box) finite. A
   non-finite one is looked up again by primitive below: it matters only if the tree holds it. */
typedef struct bvh__refit_check {
    const bvh_refit_desc *d;
    uint32_t vertices, bad_index[BVH__MAX_THREADS], bad_value[BVH__MAX_THREADS];
} bvh__refit_check;
static int bvh__box_ok(const bvh_aabb *b) {
    return bvh__finite3(&b->min.x) && bvh__finite3(&b->max.x) && b->min.x <= b->max.x && b->min.y <= b->max.y &&
           b->min.z <= b->max.z;
}
static void bvh__refit_check_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    bvh__refit_check *c = BVH__CAST(bvh__refit_check *, arg);
    const bvh_refit_desc *d = c->d;
    uint32_t bad_index = 0, bad_value = 0;
    size_t b, e, i;
    (void)team;
    if (d->boxes) {
        bvh__range(d->box_count, tid, nt, &b, &e);
        for (i = b; i < e; i++) bad_value += !bvh__box_ok(&d->boxes[i]);
    } else {
        if (d->triangles.indices) {
            bvh__range(3 * (size_t)d->triangles.triangle_count, tid, nt, &b, &e);
            for (i = b; i < e; i++) bad_index += d->triangles.indices[i] >= d->triangles.vertex_count;
        }
        bvh__range(c->vertices, tid, nt, &b, &e);
        if (d->triangles.stride == 0 || d->triangles.stride == 3 * sizeof(float)) {
            /* packed: the floats in blocks, by their bits, without branches (a vector loop) */
            const char *p = BVH__CAST(const char *, BVH__CAST(const void *, d->triangles.positions));
            bad_value += bvh__any_nonfinite(p + 3 * b * sizeof(float), 3 * (e - b));
        } else {
            for (i = b; i < e; i++) {
                float v[3];
                memcpy(v, bvh__vertex(&d->triangles, (uint32_t)i), sizeof v);
                bad_value += !bvh__finite3(v);
            }
        }
    }
    c->bad_index[tid] = bad_index;
    c->bad_value[tid] = bad_value;
}
static bvh_result bvh__refit_precheck(const bvh_tree *tree, const bvh_refit_desc *d, uint32_t nt) {
    bvh__refit_check c;
    uint32_t i, bad_index = 0, bad_value = 0;
    memset(&c, 0, sizeof c);
    c.d = d;
    c.vertices = d->triangles.indices ? d->triangles.vertex_count : 3 * d->triangles.triangle_count;
    bvh__team_run_always_on(&d->pool, &tree->allocator, nt, bvh__refit_check_fn, &c);
    for (i = 0; i < nt; i++) {
        bad_index += c.bad_index[i];
        bad_value += c.bad_value[i];
    }
    if (bad_index) return BVH_ERROR_INDEX_OUT_OF_RANGE;
    for (i = 0; bad_value && i < tree->ref_count; i++) { /* rare: do the primitives of the tree use it? */
        uint32_t p = tree->prims[i];
        if (p >= tree->prim_count) return BVH_ERROR_INVALID_TREE;
        if (d->boxes) {
            if (!bvh__box_ok(&d->boxes[p])) return BVH_ERROR_INVALID_GEOMETRY;
        } else {
            float t[9];
            bvh__fetch_triangle(&d->triangles, p, t);
            if (!bvh__finite3(t) || !bvh__finite3(t + 3) || !bvh__finite3(t + 6)) return BVH_ERROR_INVALID_GEOMETRY;
        }
    }
    return BVH_SUCCESS;
}
static bvh_result bvh__refit_check_desc(const bvh_tree *tree, const bvh_refit_desc *d) {
    const bvh_triangles *t = &d->triangles;
    if (!tree->node_count) return BVH_SUCCESS; /* nothing to move */
    if (!tree->nodes || !tree->prims) return BVH_ERROR_INVALID_TREE;
    if (tree->tris) { /* a triangle tree wants triangles, the same number */
        if (d->boxes || d->box_count || t->triangle_count != tree->prim_count || !t->positions)
            return BVH_ERROR_INVALID_ARGUMENT;
        if (t->stride != 0 && t->stride < 3 * sizeof(float)) return BVH_ERROR_INVALID_ARGUMENT;
        if ((uintptr_t)t->indices % sizeof(uint32_t)) return BVH_ERROR_INVALID_ARGUMENT;
        if (!t->indices && (uint64_t)t->vertex_count < 3 * (uint64_t)t->triangle_count)
            return BVH_ERROR_INDEX_OUT_OF_RANGE;
        return BVH_SUCCESS;
    }
    if (t->triangle_count || !d->boxes || d->box_count != tree->prim_count) return BVH_ERROR_INVALID_ARGUMENT;
    return BVH_SUCCESS;
}
BVH_API bvh_result bvh_refit(bvh_tree *tree, const bvh_refit_desc *desc) {
    bvh__refit job, *j = &job; /* a few KiB on the stack: a refit allocates nothing */
    bvh_allocator al;
    bvh_result r;
    uint32_t nt, i, bad = 0;
    if (!tree || !desc || tree->borrowed) return BVH_ERROR_INVALID_ARGUMENT; /* borrowed: a caller's const bytes */
    if ((r = bvh__refit_check_desc(tree, desc)) != BVH_SUCCESS || !tree->node_count) return r;
    al = tree->allocator;
    nt = bvh__resolve_threads(desc->threads);
    if (nt > 1 && tree->ref_count / BVH__MIN_PRIMS_PER_THREAD < nt)
        nt = tree->ref_count / BVH__MIN_PRIMS_PER_THREAD > 1 ? tree->ref_count / BVH__MIN_PRIMS_PER_THREAD : 1;
    if ((r = bvh__refit_precheck(tree, desc, nt)) != BVH_SUCCESS) return r;
    /* a valid tree and input cannot be refused from here on, where the tree starts to change */
    memset(j, 0, sizeof *j);
    j->tree = tree;
    j->tris = tree->tris ? &desc->triangles : NULL;
    j->boxes = tree->tris ? NULL : desc->boxes;
    if (tree->nodes8 && tree->tris) { /* one pass over the 8-wide layout (see above) */
        bvh__wnode_scratch sc;
        sc.ahead = sc.ahead_ix = 0;
        if (!tree->tri4 || !bvh__refit_wheads(j)) return BVH_ERROR_INVALID_TREE;
        bvh__team_run_always_on(&desc->pool, &al, nt < j->nheads ? nt : j->nheads, bvh__refit_wide_fn, j);
        for (i = 0; i < BVH__MAX_THREADS; i++) bad += j->bad[i];
        for (i = j->ntop; !bad && i-- > 0;) bad += !bvh__refit_wnode(j, j->top[i], &sc);
        bvh__stream_fence(); /* the top's packets */
        return bad ? BVH_ERROR_INVALID_TREE : BVH_SUCCESS;
    }
    if (!bvh__refit_heads(j)) return BVH_ERROR_INVALID_TREE;
    if (j->tris) bvh__team_run_always_on(&desc->pool, &al, nt, bvh__refit_tris_fn, j);
    bvh__team_run_always_on(&desc->pool, &al, nt < j->nheads ? nt : j->nheads, bvh__refit_fn, j);
    for (i = 0; i < BVH__MAX_THREADS; i++) bad += j->bad[i];
    for (i = j->ntop; !bad && i-- > 0;) bad += !bvh__refit_node(j, j->top[i]);
    return bad ? BVH_ERROR_INVALID_TREE : BVH_SUCCESS;
}

/* ============================================================================================ */
/* == save and load ============================================================================== */
/* The format (version 2): a 64-byte header of 32- and 64-bit fields in the saving machine's byte
   order, then the payload: nodes, references, and tree.tris for a triangle tree, as they lie in
   memory, then the 8-wide nodes when the tree has them (their count is what the payload size
   leaves for them). Packets are not stored: they are a copy of tree.tris in the order the wide
   nodes' groupings give, remade on load in one linear pass that checks each grouping against the
   binary tree (bvh__wide_load_node), as fast as a copy and a check of a stored copy would be, for 40%
   fewer bytes. A reader checks the byte-order marker, the header's checksum, then every size
   against the others and against caps before it allocates, then the payload's checksum, then the
   tree's structure (bvh__load_checks, with the packets), so that no input makes it read or
   allocate out of bounds (a borrowed load hashes the nodes during the structure check, which is
   safe on any bytes, and compares the checksum after it). Version 1 (0.6.0,
   no 8-wide nodes) is refused with BVH_ERROR_UNSUPPORTED_FORMAT: save such a tree again. */
/* ============================================================================================ */
#define BVH__FILE_VERSION 2u
#define BVH__FILE_ENDIAN 0x01020304u
#define BVH__FILE_HEADER 64u
#define BVH__FILE_TRIANGLES 1u /* flags: tree.tris follows the references */
#define BVH__FILE_WIDE 2u      /* flags: the 8-wide nodes follow tree.tris */
typedef char bvh__node_is_32_bytes[sizeof(bvh_node) == 32 ? 1 : -1];
static const char bvh__file_magic[8] = {'B', 'V', 'H', '.', 'T', 'R', 'E', 'E'};
typedef struct bvh__file_header {
    char magic[8];
    uint32_t version, endian, header_bytes, flags;
    uint32_t builder, node_count, ref_count, prim_count, excluded;
    uint32_t header_check; /* bvh__hash of the header with this field 0, low 32 bits */
    uint64_t payload_bytes;
    uint64_t payload_check; /* bvh__payload_check */
} bvh__file_header;
typedef char bvh__header_is_64_bytes[sizeof(bvh__file_header) == BVH__FILE_HEADER ? 1 : -1];

/* A 64-bit checksum at memory speed (about 8 bytes a cycle): four independent lanes of xxHash64's
   round (Collet) over 32-byte blocks, the tail zero-padded, the length mixed in. Not
   cryptographic: it finds damage, not forgery (the structure checks stop hostile input). */
#define BVH__P1 0x9E3779B185EBCA87ULL
#define BVH__P2 0xC2B2AE3D27D4EB4FULL
BVH__INLINE uint64_t bvh__rotl64(uint64_t x, int r) { return (x << r) | (x >> (64 - r)); }
BVH__INLINE uint64_t bvh__round64(uint64_t acc, uint64_t w) { return bvh__rotl64(acc + w * BVH__P2, 31) * BVH__P1; }
typedef struct bvh__hasher {
    uint64_t a, b, c, d;
} bvh__hasher;
static void bvh__hash_init(bvh__hasher *s, uint64_t seed) {
    s->a = seed + BVH__P1 + BVH__P2;
    s->b = seed + BVH__P2;
    s->c = seed;
    s->d = seed - BVH__P1;
}
/* Whole 32-byte blocks; a loader hashes each piece just read, while it is in cache. */
static void bvh__hash_blocks(bvh__hasher *s, const void *data, size_t size) {
    const unsigned char *p = BVH__CAST(const unsigned char *, data);
    uint64_t w[4], a = s->a, b = s->b, c = s->c, d = s->d;
    size_t i, n = size / 32;
    for (i = 0; i < n; i++, p += 32) {
        memcpy(w, p, 32);
        a = bvh__round64(a, w[0]);
        b = bvh__round64(b, w[1]);
        c = bvh__round64(c, w[2]);
        d = bvh__round64(d, w[3]);
    }
    s->a = a;
    s->b = b;
    s->c = c;
    s->d = d;
}
/* The tail (size % 32 bytes at `tail`) and the total length. */
static uint64_t bvh__hash_final(bvh__hasher *s, const void *tail, size_t size) {
    uint64_t w[4], h;
    memset(w, 0, sizeof w);
    if (size % 32) memcpy(w, tail, size % 32);
    bvh__hash_blocks(s, w, 32);
    h = bvh__rotl64(s->a, 1) + bvh__rotl64(s->b, 7) + bvh__rotl64(s->c, 12) + bvh__rotl64(s->d, 18) + (uint64_t)size;
    h ^= h >> 33;
    h *= BVH__P2;
    h ^= h >> 29;
    h *= BVH__P1;
    h ^= h >> 32;
    return h;
}
static uint64_t bvh__hash(const void *data, size_t size, uint64_t seed) {
    bvh__hasher s;
    bvh__hash_init(&s, seed);
    bvh__hash_blocks(&s, data, size);
    return bvh__hash_final(&s, size ? BVH__CAST(const unsigned char *, data) + size / 32 * 32 : NULL, size);
}
static int bvh__saves_wide(const bvh_tree *t) { return t->nodes8 && t->tris && t->node8_count; }
/* The payload's checksum: each array (nodes, references, triangles, 8-wide nodes: array 0 to 3)
   cut in pieces of BVH__PIECE bytes, each hashed with its array and number as the seed, the
   hashes summed. A sum, so that a loader can check pieces on several threads in any order; the
   seeds keep it sensitive to where a piece lies. */
#define BVH__PIECE ((size_t)1 << 18) /* a multiple of 32 bytes, of a node, a wide node and a float */
#define BVH__PIECE_NODES ((uint32_t)(BVH__PIECE / sizeof(bvh_node)))
static uint64_t bvh__piece_check(const void *p, size_t n, uint32_t array, size_t piece) {
    return bvh__hash(p, n, ((uint64_t)array << 48) ^ (uint64_t)piece);
}
static uint64_t bvh__array_check(const void *data, size_t size, uint32_t array) {
    const unsigned char *p = BVH__CAST(const unsigned char *, data);
    uint64_t h = 0;
    size_t i;
    for (i = 0; i * BVH__PIECE < size; i++)
        h += bvh__piece_check(p + i * BVH__PIECE,
                              size - i * BVH__PIECE < BVH__PIECE ? size - i * BVH__PIECE : BVH__PIECE, array, i);
    return h;
}
static uint64_t bvh__payload_check(const bvh_tree *t) {
    uint64_t h = bvh__array_check(t->nodes, (size_t)t->node_count * sizeof(bvh_node), 0);
    h += bvh__array_check(t->prims, (size_t)t->ref_count * sizeof(uint32_t), 1);
    if (t->tris) h += bvh__array_check(t->tris, (size_t)t->ref_count * 9 * sizeof(float), 2);
    if (bvh__saves_wide(t)) h += bvh__array_check(t->nodes8, (size_t)t->node8_count * sizeof(bvh_node8), 3);
    return h;
}
static uint32_t bvh__header_check(bvh__file_header h) {
    h.header_check = 0;
    return (uint32_t)bvh__hash(&h, sizeof h, 0x42);
}
/* Payload bytes of a tree of these counts, or 0 where they overflow. */
static uint64_t bvh__payload_bytes(uint32_t nodes, uint32_t refs, int tris, uint32_t nodes8) {
    return (uint64_t)nodes * sizeof(bvh_node) + (uint64_t)refs * sizeof(uint32_t) +
           (tris ? (uint64_t)refs * 9 * sizeof(float) : 0) + (uint64_t)nodes8 * sizeof(bvh_node8);
}
BVH_API size_t bvh_save_size(const bvh_tree *tree) {
    if (!tree) return 0;
    return BVH__FILE_HEADER + (size_t)bvh__payload_bytes(tree->node_count, tree->ref_count, tree->tris != NULL,
                                                         bvh__saves_wide(tree) ? tree->node8_count : 0);
}
/* Large arrays go out in pieces of 64 MiB at most: a callback may take a 32-bit length. */
static bvh_result bvh__write_all(bvh_write_fn write, void *user, const void *data, size_t size) {
    const char *p = BVH__CAST(const char *, data);
    while (size) {
        size_t n = size < ((size_t)1 << 26) ? size : ((size_t)1 << 26);
        if (write(user, p, n) != n) return BVH_ERROR_IO;
        p += n;
        size -= n;
    }
    return BVH_SUCCESS;
}
BVH_API bvh_result bvh_save(const bvh_tree *tree, bvh_write_fn write, void *user) {
    bvh__file_header h;
    bvh_result r;
    if (!tree || !write) return BVH_ERROR_INVALID_ARGUMENT;
    if (tree->node_count && (!tree->nodes || !tree->prims)) return BVH_ERROR_INVALID_TREE;
    memset(&h, 0, sizeof h);
    memcpy(h.magic, bvh__file_magic, sizeof h.magic);
    h.version = BVH__FILE_VERSION;
    h.endian = BVH__FILE_ENDIAN;
    h.header_bytes = BVH__FILE_HEADER;
    h.flags = (tree->tris ? BVH__FILE_TRIANGLES : 0u) | (bvh__saves_wide(tree) ? BVH__FILE_WIDE : 0u);
    h.builder = (uint32_t)tree->builder;
    h.node_count = tree->node_count;
    h.ref_count = tree->ref_count;
    h.prim_count = tree->prim_count;
    h.excluded = tree->excluded;
    h.payload_bytes = bvh__payload_bytes(tree->node_count, tree->ref_count, tree->tris != NULL,
                                         bvh__saves_wide(tree) ? tree->node8_count : 0);
    h.payload_check = bvh__payload_check(tree);
    h.header_check = bvh__header_check(h);
    if ((r = bvh__write_all(write, user, &h, sizeof h)) != BVH_SUCCESS) return r;
    if ((r = bvh__write_all(write, user, tree->nodes, (size_t)tree->node_count * sizeof(bvh_node))) != BVH_SUCCESS)
        return r;
    if ((r = bvh__write_all(write, user, tree->prims, (size_t)tree->ref_count * sizeof(uint32_t))) != BVH_SUCCESS)
        return r;
    if (tree->tris) r = bvh__write_all(write, user, tree->tris, (size_t)tree->ref_count * 9 * sizeof(float));
    if (r == BVH_SUCCESS && bvh__saves_wide(tree))
        r = bvh__write_all(write, user, tree->nodes8, (size_t)tree->node8_count * sizeof(bvh_node8));
    return r;
}

/* The load source: a callback, or a memory buffer read through a cursor. */
typedef struct bvh__reader {
    const bvh_load_desc *d;
    const bvh_tree *tree; /* its allocator, for the team */
    size_t pos;
} bvh__reader;
static bvh_result bvh__read_all(bvh__reader *rd, void *out, size_t size) {
    char *p = BVH__CAST(char *, out);
    if (!rd->d->read) {
        if (size > rd->d->size - rd->pos) return BVH_ERROR_TRUNCATED;
        if (size) memcpy(out, BVH__CAST(const char *, rd->d->data) + rd->pos, size);
        rd->pos += size;
        return BVH_SUCCESS;
    }
    while (size) {
        size_t n = size < ((size_t)1 << 26) ? size : ((size_t)1 << 26);
        if (rd->d->read(rd->d->user, p, n) != n) return BVH_ERROR_TRUNCATED;
        p += n;
        size -= n;
    }
    return BVH_SUCCESS;
}
/* The payload's values a valid tree cannot hold and the validator does not look at: non-finite
   triangle coordinates (bvh_build refuses them, traversal assumes none). Checked by bits, without
   branches. (Leaves of more than BVH__MAX_LEAF references, which no builder makes, are refused by
   the ordered check, bvh__validate_linear, which reaches every node.) */
static int bvh__floats_finite(const float *t, size_t n) { return !bvh__any_nonfinite(t, n); }
/* A payload array read in pieces (BVH__PIECE), each hashed (bvh__payload_check) and checked as
   `kind` says (2: triangles, finite) while it is still in cache: one pass over the memory. From a
   memory buffer, the pieces are shared out over the load's team in contiguous runs (each thread
   first touches its own fresh pages: bvh__touch_pages says why); from a stream, read in order. */
typedef struct bvh__load_array {
    const unsigned char *src; /* the memory buffer's bytes; NULL: a stream */
    unsigned char *out;
    size_t size;
    uint32_t array;
    int kind;
    uint64_t check[BVH__MAX_THREADS];
    int bad[BVH__MAX_THREADS];
} bvh__load_array;
static void bvh__load_piece(bvh__load_array *a, size_t i, uint32_t tid) {
    unsigned char *p = a->out + i * BVH__PIECE;
    size_t n = a->size - i * BVH__PIECE < BVH__PIECE ? a->size - i * BVH__PIECE : BVH__PIECE;
    if (a->src && a->src != a->out) memcpy(p, a->src + i * BVH__PIECE, n); /* a borrowed array: in place */
    a->check[tid] += bvh__piece_check(p, n, a->array, i);
    if (a->kind == 2)
        a->bad[tid] |= !bvh__floats_finite(BVH__CAST(const float *, BVH__CAST(void *, p)), n / sizeof(float));
}
static void bvh__load_array_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    bvh__load_array *a = BVH__CAST(bvh__load_array *, arg);
    size_t i, b, e;
    (void)team;
    bvh__range((a->size + BVH__PIECE - 1) / BVH__PIECE, tid, nt, &b, &e); /* each thread its own pages */
    for (i = b; i < e; i++) bvh__load_piece(a, i, tid);
}
static bvh_result bvh__read_array(bvh__reader *rd, void *out, size_t size, int kind, uint32_t array, uint32_t threads,
                                  uint64_t *check, int *bad) {
    bvh__load_array a;
    size_t i;
    bvh_result r;
    memset(&a, 0, sizeof a);
    a.out = BVH__CAST(unsigned char *, out);
    a.size = size;
    a.array = array;
    a.kind = kind;
    if (!rd->d->read) { /* memory: the pieces on the team (at least 1 MiB each thread) */
        uint32_t nt = (uint32_t)(size >> 20) < threads ? (uint32_t)(size >> 20) : threads;
        if (size > rd->d->size - rd->pos) return BVH_ERROR_TRUNCATED;
        a.src = BVH__CAST(const unsigned char *, rd->d->data) + rd->pos;
        rd->pos += size;
        bvh__team_run_always_on(&rd->d->pool, &rd->tree->allocator, nt ? nt : 1, bvh__load_array_fn, &a);
    } else {
        for (i = 0; i * BVH__PIECE < size; i++) {
            size_t n = size - i * BVH__PIECE < BVH__PIECE ? size - i * BVH__PIECE : BVH__PIECE;
            if ((r = bvh__read_all(rd, a.out + i * BVH__PIECE, n)) != BVH_SUCCESS) return r;
            bvh__load_piece(&a, i, 0);
        }
    }
    for (i = 0; i < BVH__MAX_THREADS; i++) {
        *check += a.check[i];
        *bad |= a.bad[i];
    }
    return BVH_SUCCESS;
}
/* A borrowed array's pointer (bvh_load_desc.borrow) as the tree's field type; nothing writes
   through it (bvh_refit refuses a borrowed tree). */
static void *bvh__unconst(const void *p) {
    void *q;
    memcpy(&q, &p, sizeof q);
    return q;
}
static uint32_t bvh__bswap32(uint32_t x) {
    return (x >> 24) | ((x >> 8) & 0xff00u) | ((x << 8) & 0xff0000u) | (x << 24);
}
/* The header's checks, before any allocation: what it says must be a tree bvh_build could make. */
static bvh_result bvh__check_header(const bvh__file_header *h, const bvh_load_desc *d) {
    uint64_t payload;
    if (memcmp(h->magic, bvh__file_magic, sizeof h->magic) != 0) return BVH_ERROR_CORRUPT;
    if (h->endian != BVH__FILE_ENDIAN)
        return bvh__bswap32(h->endian) == BVH__FILE_ENDIAN ? BVH_ERROR_UNSUPPORTED_FORMAT : BVH_ERROR_CORRUPT;
    if (h->header_check != bvh__header_check(*h)) return BVH_ERROR_CORRUPT;
    if (h->version != BVH__FILE_VERSION) return BVH_ERROR_UNSUPPORTED_FORMAT;
    if (h->header_bytes != BVH__FILE_HEADER || (h->flags & ~(BVH__FILE_TRIANGLES | BVH__FILE_WIDE)) ||
        ((h->flags & BVH__FILE_WIDE) && !(h->flags & BVH__FILE_TRIANGLES)))
        return BVH_ERROR_CORRUPT;
    if (h->builder == BVH_BUILDER_DEFAULT || h->builder >= BVH_BUILDER_COUNT) return BVH_ERROR_CORRUPT;
    if (h->prim_count > BVH__MAX_PRIMS || h->excluded > h->prim_count) return BVH_ERROR_CORRUPT;
    /* every primitive kept is referenced; only a splitting builder references one twice (at most
       doubling them: its budget is at most 1); a binary tree has fewer nodes than twice its leaves */
    if (h->ref_count < h->prim_count - h->excluded || h->ref_count > 2 * (h->prim_count - h->excluded))
        return BVH_ERROR_CORRUPT;
    if (h->ref_count == 0 ? h->node_count != 0 : h->node_count == 0 || h->node_count > 2 * (uint64_t)h->ref_count - 1)
        return BVH_ERROR_CORRUPT;
    payload = bvh__payload_bytes(h->node_count, h->ref_count, (h->flags & BVH__FILE_TRIANGLES) != 0, 0);
    if (h->flags & BVH__FILE_WIDE) { /* the rest: at least one wide node, each from its own binary node */
        uint64_t wide = h->payload_bytes - payload;
        if (h->payload_bytes <= payload || wide % sizeof(bvh_node8) || wide / sizeof(bvh_node8) > h->node_count)
            return BVH_ERROR_CORRUPT;
        payload = h->payload_bytes;
    }
    if (h->payload_bytes != payload) return BVH_ERROR_CORRUPT;
    if (payload > (uint64_t)((size_t)-1 / 2)) return BVH_ERROR_OUT_OF_MEMORY;
    if (d->max_bytes && payload > d->max_bytes) return BVH_ERROR_CORRUPT;
    return BVH_SUCCESS;
}
/* bvh_validate's checks of the binary tree in one forward pass, for bvh_load (but the leaves'
   triangles, checked on the team by bvh__load_checks, and the 8-wide nodes, by bvh__wide_load_node):
   every builder stores children after their parent, so when node i is met its parent, if it has
   one, was met before. Each node but the root must be reached exactly once and no deeper than
   BVH_MAX_DEPTH (depth + 1 per node, a byte, 0 = not reached: then never), its box valid and
   (with `boxes`) inside its parent's, a leaf's references inside the array, their primitives in
   range (once each unless the builder splits). Without `boxes` the 8-wide pass checks each
   interior node's children boxes (bvh__children_inside), where it reads them anyway: here a child
   lies far from its parent in a depth-first tree, and its box is a cache miss. With `node_check`
   (a borrowed load, whose read pass leaves the nodes to this one) each piece of the nodes is
   hashed into it as the pass reaches it (bvh__payload_check's terms): the nodes are read from
   memory once, not twice. Leaves of more than BVH__MAX_LEAF references are refused here, for
   every load. The primitives are counted in a byte
   per primitive, or, where they far outnumber the references (a build that left most of them
   out, whose file is small), in a sorted copy of the references: what load allocates stays in
   proportion to the file. */
static int bvh__cmp_u32(const void *a, const void *b) {
    const uint32_t x = *(const uint32_t *)a, y = *(const uint32_t *)b;
    return (x > y) - (x < y);
}
static bvh_result bvh__validate_linear(const bvh_tree *t, int boxes, uint64_t *node_check) {
    bvh_allocator al = t->allocator;
    const int dense = t->prim_count <= 4 * (uint64_t)t->ref_count + 65536;
    uint8_t *depth = BVH__ALLOC(&al, uint8_t, t->node_count);
    uint8_t *used = dense ? BVH__ALLOC(&al, uint8_t, t->prim_count ? t->prim_count : 1) : NULL;
    uint32_t *sorted = dense ? NULL : BVH__ALLOC(&al, uint32_t, t->ref_count ? t->ref_count : 1);
    uint8_t *covered = BVH__ALLOC(&al, uint8_t, t->ref_count ? t->ref_count : 1); /* per reference, by a leaf */
    uint64_t refs = 0;
    uint32_t i, k, n_used = 0;
    int splits = t->ref_count != t->prim_count - t->excluded;
    bvh_result r = BVH_ERROR_INVALID_TREE;
    if (!depth || !(used || sorted) || !covered) {
        r = BVH_ERROR_OUT_OF_MEMORY;
        goto done;
    }
    if (splits && !bvh__builders[t->builder].info.splits_references) goto done;
    memset(depth, 0, t->node_count);
    if (used) memset(used, 0, t->prim_count ? t->prim_count : 1);
    memset(covered, 0, t->ref_count ? t->ref_count : 1);
    depth[0] = 1;
    for (i = 0; i < t->node_count; i++) {
        const bvh_node *n = &t->nodes[i];
        bvh_aabb box;
        if (node_check && i % BVH__PIECE_NODES == 0) {
            const uint32_t m = t->node_count - i < BVH__PIECE_NODES ? t->node_count - i : BVH__PIECE_NODES;
            *node_check += bvh__piece_check(n, (size_t)m * sizeof(bvh_node), 0, i / BVH__PIECE_NODES);
        }
        box = bvh__node_box(n);
        if (!depth[i] || !(box.min.x <= box.max.x && box.min.y <= box.max.y && box.min.z <= box.max.z)) goto done;
        if (n->count) {
            if (n->index > t->ref_count || n->count > t->ref_count - n->index || n->count > BVH__MAX_LEAF) goto done;
            refs += n->count;
            for (k = n->index; k < n->index + n->count; k++) {
                uint32_t p = t->prims[k];
                if (covered[k]++) goto done; /* with refs == ref_count: each reference in one leaf */
                if (p >= t->prim_count) goto done;
                if (!used) continue;
                if (used[p] && !splits) goto done;
                n_used += !used[p];
                used[p] = 1;
            }
            continue;
        }
        if (n->index <= i || n->index >= t->node_count - 1 || depth[i] > BVH_MAX_DEPTH) goto done;
        for (k = n->index; k < n->index + 2; k++) {
            if (depth[k] || (boxes && !bvh_aabb_contains(box, bvh__node_box(&t->nodes[k])))) goto done;
            depth[k] = (uint8_t)(depth[i] + 1);
        }
    }
    if (refs != t->ref_count) goto done;
    if (sorted) { /* the distinct primitives of the references (all in range, checked above) */
        if (t->ref_count) memcpy(sorted, t->prims, (size_t)t->ref_count * sizeof *sorted);
        qsort(sorted, t->ref_count, sizeof *sorted, bvh__cmp_u32);
        for (k = 0; k < t->ref_count; k++) {
            if (k && sorted[k] == sorted[k - 1]) {
                if (!splits) goto done;
                continue;
            }
            n_used++;
        }
    }
    if (n_used == t->prim_count - t->excluded) r = BVH_SUCCESS;
done:
    bvh__free(&al, depth);
    bvh__free(&al, used);
    bvh__free(&al, sorted);
    bvh__free(&al, covered);
    return r;
}
/* The triangles of leaf n inside its box (for split references, clipped: each overlapping it).
   The leaf's range must have been checked. */
static int bvh__leaf_tris_ok(const float *tris, const bvh_node *n, int splits) {
    bvh_aabb box = bvh__node_box(n);
    uint32_t k;
    if (!splits) return bvh_aabb_contains(box, bvh__tris_box(tris + 9 * (size_t)n->index, n->count));
    for (k = n->index; k < n->index + n->count; k++) {
        bvh_aabb pb = bvh__tri_box(tris + 9 * (size_t)k);
        if (!(pb.min.x <= box.max.x && pb.min.y <= box.max.y && pb.min.z <= box.max.z && pb.max.x >= box.min.x &&
              pb.max.y >= box.min.y && pb.max.z >= box.min.z))
            return 0;
    }
    return 1;
}
/* The saved 8-wide nodes (in tree.nodes8, tree.node8_count; tree.tri4_count packets, the sum of
   their leaf counts) made whole: boxes from the binary nodes and packets from tree.tris, following
   each node's grouping, which must fit the binary tree (validated before): the root's head is the
   binary root, each interior slot a wide node after its parent whose head is that slot (so every
   wide node but the root has one parent: a tree, as deep as the binary one at most, and each
   binary node in one grouping), each leaf slot's packets as many as its references fill, inside
   the array and in no other slot. Two linear passes: the links and packet ranges on one thread
   (bvh__wide_links), then the groupings, boxes and packets on the team (each node writes only its
   own slots and packets, whose ranges the first pass found disjoint). The leaf slots' walks meet
   every binary leaf once, so the leaves' triangles are checked against their boxes here, while
   they are read for the packets. Each step checks the binary nodes it follows (indices in range,
   children after their parent), so that this pass may run while bvh__validate_linear checks the
   binary tree on another thread: the tree is accepted only if both pass. */
/* Interior node x's two children inside its box (x's index checked in range). */
static int bvh__children_inside(const bvh_node *nodes, uint32_t x) {
    const bvh_aabb box = bvh__node_box(&nodes[x]);
    return bvh_aabb_contains(box, bvh__node_box(&nodes[nodes[x].index])) &&
           bvh_aabb_contains(box, bvh__node_box(&nodes[nodes[x].index + 1]));
}
static int bvh__wide_load_node(bvh_tree *t, uint32_t w, int splits, bvh__wnode_scratch *sc) {
    bvh_node8 *n = &t->nodes8[w];
    bvh__group g;
    uint32_t i, a, k, npre = 0, nref = 0;
    if (!bvh__group_read(t->nodes, t->node_count, n, &g)) return 0;
    if (g.nslot == 1 && (w || !n->count[0])) return 0; /* only a root that is a leaf slot */
    for (i = 0; i < g.nopen; i++)
        if (!bvh__children_inside(t->nodes, g.open[i])) return 0;
    for (i = 0; i < g.nslot; i++) { /* the leaf slots' walks first, their leaves' triangles asked for */
        if (n->count[i]) {
            const uint32_t r0 = nref, p0 = npre;
            if (!bvh__slot_walk(t, g.slot[i], sc->pre, &npre, sc->refs, &nref)) return 0;
            if (n->count[i] != (nref - r0 + BVH__PACKET - 1) / BVH__PACKET) return 0;
            for (k = p0; k < npre; k++) {
                const bvh_node *x = &t->nodes[sc->pre[k]]; /* a leaf's range: checked by the walk */
                const char *f = BVH__CAST(const char *, BVH__CAST(const void *, t->tris + 9 * (size_t)x->index));
                const char *e = f + 36 * (size_t)x->count;
                if (!x->count) continue;
                for (; f < e; f += 64) BVH__PREFETCH(f);
                BVH__PREFETCH(e - 1);
            }
        }
        sc->pre_end[i] = npre;
        sc->ref_end[i] = nref;
    }
    for (i = 0; i < BVH__W; i++) {
        if (i >= g.nslot) {
            if (n->count[i] || n->child[i]) return 0;
            for (a = 0; a < 3; a++) {
                n->min[a][i] = BVH_INF;
                n->max[a][i] = -BVH_INF;
            }
            continue;
        }
        if (n->count[i]) {
            const uint32_t r0 = i ? sc->ref_end[i - 1] : 0;
            for (k = i ? sc->pre_end[i - 1] : 0; k < sc->pre_end[i]; k++) { /* bvh__validate_linear leaves them here */
                const bvh_node *x = &t->nodes[sc->pre[k]];
                if (x->count ? !bvh__leaf_tris_ok(t->tris, x, splits) : !bvh__children_inside(t->nodes, sc->pre[k]))
                    return 0;
            }
            bvh__packets_write(sc->refs + r0, sc->ref_end[i] - r0, t->prims, t->tris, t->tri4 + n->child[i]);
        } else if (t->nodes8[n->child[i]].head != g.slot[i]) {
            return 0;
        }
        bvh__node8_box(n, i, t->nodes[g.slot[i]].min, t->nodes[g.slot[i]].max);
    }
    memset(n->pad, 0, sizeof n->pad); /* order is kept: bvh__group_read checked it */
    return 1;
}
/* The 8-wide nodes' links and packet ranges (see above), on one thread: 0 where they do not fit. */
static int bvh__wide_links(const bvh_tree *t, uint8_t *parent, uint8_t *cover) {
    uint32_t w, i, k;
    memset(parent, 0, t->node8_count);
    memset(cover, 0, t->tri4_count ? t->tri4_count : 1);
    if (t->nodes8[0].head != 0) return 0;
    for (w = 0; w < t->node8_count; w++) {
        const bvh_node8 *n = &t->nodes8[w];
        for (i = 0; i < BVH__W; i++)
            if (n->count[i]) {
                if (n->child[i] > t->tri4_count || n->count[i] > t->tri4_count - n->child[i]) return 0;
                for (k = n->child[i]; k < n->child[i] + n->count[i]; k++)
                    if (cover[k]++) return 0;
            } else if (n->child[i] && (n->child[i] <= w || n->child[i] >= t->node8_count || parent[n->child[i]]++)) {
                return 0;
            }
    }
    for (w = 1; w < t->node8_count; w++)
        if (!parent[w]) return 0;
    return 1; /* packets: each in one slot, and as many as the slots' counts */
}
/* The checks of a loaded tree and the remaking of its 8-wide layout in one team pass: thread 0
   runs bvh__validate_linear, the one pass that needs order, while every thread takes chunks of
   the work that needs none (an atomic counter; without it a fixed share each): the 8-wide nodes
   (bvh__wide_load_node, which checks the leaves' triangles as it packs them), or, without the
   8-wide layout, the leaves' triangles by chunks of binary nodes. */
#define BVH__LOAD_CHUNK 64u /* 8-wide nodes a thread takes at a time (binary nodes: 64 times more) */
typedef struct bvh__load_job {
    bvh_tree *tree;
    size_t next, count; /* the next chunk; the items (8-wide nodes, else binary nodes) */
    uint32_t chunk;
    int splits;
    bvh_result checked;   /* bvh__validate_linear's */
    uint64_t *node_check; /* a borrowed load's: the nodes' checksum terms, added by that pass */
    uint32_t bad[BVH__MAX_THREADS];
} bvh__load_job;
static int bvh__load_items(bvh__load_job *j, size_t b, size_t e, bvh__wnode_scratch *sc) {
    bvh_tree *t = j->tree;
    size_t i;
    for (i = b; i < e; i++) {
        if (t->nodes8) {
            bvh__refit_ask_next(t, (uint32_t)i + 3, (uint32_t)i + 2, (uint32_t)i + 1); /* as the refit's walk */
            if (!bvh__wide_load_node(t, (uint32_t)i, j->splits, sc)) return 0;
        } else {
            const bvh_node *n = &t->nodes[i]; /* its range is checked here: the linear pass may not be there yet */
            if (n->count && (n->index > t->ref_count || n->count > t->ref_count - n->index ||
                             !bvh__leaf_tris_ok(t->tris, n, j->splits)))
                return 0;
        }
    }
    return 1;
}
static void bvh__load_fn(void *arg, uint32_t tid, uint32_t nt, bvh__team *team) {
    bvh__load_job *j = BVH__CAST(bvh__load_job *, arg);
    bvh__wnode_scratch sc; /* 20 KiB of this thread's stack */
    size_t b, e;
    (void)team;
    if (tid == 0) j->checked = bvh__validate_linear(j->tree, j->tree->nodes8 == NULL, j->node_check);
#if defined(__GNUC__) || defined(__clang__)
    (void)nt;
    while (!j->bad[tid] && (b = __atomic_fetch_add(&j->next, (size_t)j->chunk, __ATOMIC_RELAXED)) < j->count) {
        e = j->count - b < j->chunk ? j->count : b + j->chunk;
        j->bad[tid] = !bvh__load_items(j, b, e, &sc);
    }
#else
    bvh__range(j->count, tid, nt, &b, &e);
    j->bad[tid] = !bvh__load_items(j, b, e, &sc);
#endif
}
static bvh_result bvh__load_checks(bvh_tree *t, const bvh_thread_pool *pool, uint32_t threads, uint64_t *node_check) {
    size_t marks = t->nodes8 ? t->node8_count : 1, covers = t->nodes8 && t->tri4_count ? t->tri4_count : 1;
    uint8_t *parent = BVH__ALLOC(&t->allocator, uint8_t, marks), *cover = BVH__ALLOC(&t->allocator, uint8_t, covers);
    bvh__load_job job;
    bvh_result r = BVH_ERROR_CORRUPT;
    uint32_t i, nt;
    memset(&job, 0, sizeof job);
    if (!parent || !cover) {
        r = BVH_ERROR_OUT_OF_MEMORY;
        goto done;
    }
    if (t->nodes8 && !bvh__wide_links(t, parent, cover)) goto done;
    job.tree = t;
    job.node_check = node_check;
    job.splits = t->ref_count != t->prim_count - t->excluded;
    job.count = t->nodes8 ? t->node8_count : t->tris ? t->node_count : 0;
    job.chunk = t->nodes8 ? BVH__LOAD_CHUNK : 64 * BVH__LOAD_CHUNK;
    nt = t->ref_count / BVH__MIN_PRIMS_PER_THREAD;
    nt = threads < nt ? threads : nt ? nt : 1;
    bvh__touch_pages(pool, &t->allocator, nt, t->tri4, (size_t)t->tri4_count * sizeof(bvh_tri4));
    bvh__team_run_always_on(pool, &t->allocator, nt, bvh__load_fn, &job);
    if ((r = job.checked) != BVH_SUCCESS) goto done; /* INVALID_TREE: the caller says CORRUPT */
    for (i = 0; i < BVH__MAX_THREADS; i++)
        if (job.bad[i]) r = BVH_ERROR_CORRUPT;
done:
    bvh__free(&t->allocator, parent);
    bvh__free(&t->allocator, cover);
    return r;
}
/* The packets n saved wide nodes at `nodes8` (any alignment: a caller's buffer) need, the sum of
   their leaf counts, or BVH_INVALID if more than refs: each packet holds a reference of its own. */
static uint32_t bvh__wide_packet_sum(const void *nodes8, uint32_t n, uint32_t refs) {
    const unsigned char *c = BVH__CAST(const unsigned char *, nodes8) + offsetof(bvh_node8, count);
    uint64_t sum = 0;
    uint32_t i, k;
    for (i = 0; i < n; i++, c += sizeof(bvh_node8))
        for (k = 0; k < BVH__W; k++) sum += c[k];
    return sum > refs ? BVH_INVALID : (uint32_t)sum;
}
BVH_API bvh_result bvh_load(bvh_tree *tree, const bvh_load_desc *desc) {
    bvh__file_header h;
    bvh__reader rd;
    bvh_result r;
    uint64_t check;
    bvh_node8 *wide = NULL; /* the saved 8-wide nodes from a stream, until the block that holds the packets too */
    uint32_t nodes8 = 0, packets = 0, nt;
    int bad = 0;
    if (!tree) return BVH_ERROR_INVALID_ARGUMENT;
    memset(tree, 0, sizeof *tree);
    if (!desc || (!desc->read && !desc->data && desc->size)) return BVH_ERROR_INVALID_ARGUMENT;
    if (desc->trace_width != 0 && desc->trace_width != 2 && desc->trace_width != 8) return BVH_ERROR_INVALID_ARGUMENT;
    if (desc->borrow > 1 || (desc->borrow && (desc->read || (uintptr_t)desc->data % sizeof(float))))
        return BVH_ERROR_INVALID_ARGUMENT;
    if (!desc->allocator.alloc != !desc->allocator.free) return BVH_ERROR_INVALID_ARGUMENT;
    if ((r = bvh__allocator_ok(&desc->allocator)) != BVH_SUCCESS) return r;
    tree->allocator = desc->allocator;
    rd.d = desc;
    rd.tree = tree;
    rd.pos = 0;
    nt = bvh__resolve_threads(desc->threads);
    if ((r = bvh__read_all(&rd, &h, sizeof h)) != BVH_SUCCESS) return r;
    if ((r = bvh__check_header(&h, desc)) != BVH_SUCCESS) return r;
    /* a memory buffer bounds the payload before anything is allocated */
    if (!desc->read && h.payload_bytes > (uint64_t)(desc->size - rd.pos)) return BVH_ERROR_TRUNCATED;
    tree->builder = BVH__CAST(bvh_builder, h.builder);
    tree->prim_count = h.prim_count;
    tree->excluded = h.excluded;
    if (!h.node_count) return BVH_SUCCESS;
    if (h.flags & BVH__FILE_WIDE)
        nodes8 =
            (uint32_t)((h.payload_bytes - bvh__payload_bytes(h.node_count, h.ref_count, 1, 0)) / sizeof(bvh_node8));
    if (desc->borrow) { /* the arrays where they lie (the payload fits the buffer: checked above) */
        const char *b = BVH__CAST(const char *, desc->data) + rd.pos;
        tree->borrowed = 1;
        tree->nodes = BVH__CAST(bvh_node *, bvh__unconst(b));
        tree->prims = BVH__CAST(uint32_t *, bvh__unconst(b + (size_t)h.node_count * sizeof(bvh_node)));
        if (h.flags & BVH__FILE_TRIANGLES)
            tree->tris = BVH__CAST(float *, bvh__unconst(b + (size_t)h.node_count * sizeof(bvh_node) +
                                                         (size_t)h.ref_count * sizeof(uint32_t)));
    } else {
        tree->nodes = BVH__ALLOC(&tree->allocator, bvh_node, h.node_count);
        tree->prims = BVH__ALLOC(&tree->allocator, uint32_t, h.ref_count);
        if (h.flags & BVH__FILE_TRIANGLES) tree->tris = BVH__ALLOC(&tree->allocator, float, 9 * (size_t)h.ref_count);
    }
    if (!tree->nodes || !tree->prims || (!tree->tris && (h.flags & BVH__FILE_TRIANGLES))) {
        r = BVH_ERROR_OUT_OF_MEMORY;
        goto fail;
    }
    check = 0;        /* bvh__payload_check's sum */
    if (desc->borrow) /* the nodes: hashed by the ordered check (bvh__validate_linear) */
        rd.pos += (size_t)h.node_count * sizeof(bvh_node);
    else if ((r = bvh__read_array(&rd, tree->nodes, (size_t)h.node_count * sizeof(bvh_node), 0, 0, nt, &check, &bad)) !=
             BVH_SUCCESS)
        goto fail;
    if ((r = bvh__read_array(&rd, tree->prims, (size_t)h.ref_count * sizeof(uint32_t), 0, 1, nt, &check, &bad)) !=
            BVH_SUCCESS ||
        (tree->tris && (r = bvh__read_array(&rd, tree->tris, (size_t)h.ref_count * 9 * sizeof(float), 2, 2, nt, &check,
                                            &bad)) != BVH_SUCCESS))
        goto fail;
    if (nodes8 && desc->trace_width != 2 && !desc->read) {
        /* from memory, the packets are counted in the buffer and the nodes read into their block,
           not through a copy (the count only sizes the block: the checks below hold as for a
           stream) */
        const char *src = BVH__CAST(const char *, desc->data) + rd.pos;
        if ((packets = bvh__wide_packet_sum(src, nodes8, h.ref_count)) == BVH_INVALID) {
            r = BVH_ERROR_CORRUPT;
            goto fail;
        }
        if ((r = bvh__wide_alloc(tree, &tree->allocator, nodes8, packets)) != BVH_SUCCESS ||
            (r = bvh__read_array(&rd, tree->nodes8, (size_t)nodes8 * sizeof(bvh_node8), 0, 3, nt, &check, &bad)) !=
                BVH_SUCCESS)
            goto fail;
    } else if (nodes8) {
        if (!(wide = BVH__ALLOC(&tree->allocator, bvh_node8, nodes8))) {
            r = BVH_ERROR_OUT_OF_MEMORY;
            goto fail;
        }
        if ((r = bvh__read_array(&rd, wide, (size_t)nodes8 * sizeof(bvh_node8), 0, 3, nt, &check, &bad)) != BVH_SUCCESS)
            goto fail;
    }
    tree->node_count = h.node_count;
    tree->ref_count = h.ref_count;
    if ((check != h.payload_check && !desc->borrow) || bad) {
        r = BVH_ERROR_CORRUPT;
        goto fail;
    }
    if (wide && desc->trace_width != 2) { /* the saved layout from a stream, its packets remade */
        if ((packets = bvh__wide_packet_sum(wide, nodes8, h.ref_count)) == BVH_INVALID) {
            r = BVH_ERROR_CORRUPT;
            goto fail;
        }
        if ((r = bvh__wide_alloc(tree, &tree->allocator, nodes8, packets)) != BVH_SUCCESS) goto fail;
        memcpy(tree->nodes8, wide, (size_t)nodes8 * sizeof(bvh_node8));
    }
    r = bvh__load_checks(tree, &desc->pool, nt, desc->borrow ? &check : NULL); /* and the 8-wide layout remade */
    if (r == BVH_SUCCESS && check != h.payload_check) r = BVH_ERROR_CORRUPT;   /* borrowed: now whole */
    if (r != BVH_SUCCESS) {
        if (r == BVH_ERROR_INVALID_TREE) r = BVH_ERROR_CORRUPT;
        goto fail;
    }
    if (!tree->nodes8 && tree->tris && desc->trace_width == 8) { /* saved without: made as bvh_build does */
        if ((r = bvh__make_wide(tree, &tree->allocator, &desc->pool, nt)) != BVH_SUCCESS) {
            if (r == BVH_ERROR_INVALID_TREE) r = BVH_ERROR_CORRUPT; /* children before their parent */
            goto fail;
        }
    }
    bvh__free(&tree->allocator, wide);
    return BVH_SUCCESS;
fail:
    bvh__free(&tree->allocator, wide);
    bvh_free(tree);
    tree->builder = BVH_BUILDER_DEFAULT;
    return r;
}

/* ============================================================================================ */
/* == camera ===================================================================================== */
/* ============================================================================================ */
static bvh_vec3 bvh__v3(float x, float y, float z) {
    bvh_vec3 v;
    v.x = x;
    v.y = y;
    v.z = z;
    return v;
}
static bvh_vec3 bvh__normalize(bvh_vec3 v) {
    float l = sqrtf(v.x * v.x + v.y * v.y + v.z * v.z);
    return l > 0.0f ? bvh__v3(v.x / l, v.y / l, v.z / l) : v;
}
static bvh_vec3 bvh__cross(bvh_vec3 a, bvh_vec3 b) {
    return bvh__v3(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}
BVH_API bvh_camera bvh_camera_standard(bvh_aabb b, uint32_t width, uint32_t height) {
    bvh_camera cam;
    bvh_vec3 c = bvh_aabb_centroid(b), d = bvh__normalize(bvh__v3(1.0f, 0.6f, 1.3f));
    float dx = b.max.x - b.min.x, dy = b.max.y - b.min.y, dz = b.max.z - b.min.z;
    float diag = sqrtf(dx * dx + dy * dy + dz * dz), th = tanf(30.0f * 3.14159265f / 180.0f);
    float aspect;
    bvh_vec3 r, u;
    width = width ? width : 1;
    height = height ? height : 1;
    aspect = (float)width / (float)height;
    if (!(diag > 0.0f) || !bvh__finite(diag)) diag = 1.0f;
    if (!bvh__finite(c.x) || !bvh__finite(c.y) || !bvh__finite(c.z)) c = bvh__v3(0.0f, 0.0f, 0.0f);
    cam.eye = bvh__v3(c.x + d.x * 1.5f * diag, c.y + d.y * 1.5f * diag, c.z + d.z * 1.5f * diag);
    cam.forward = bvh__v3(-d.x, -d.y, -d.z);
    r = bvh__normalize(bvh__cross(cam.forward, bvh__v3(0.0f, 1.0f, 0.0f)));
    u = bvh__cross(r, cam.forward);
    cam.right = bvh__v3(r.x * th * aspect, r.y * th * aspect, r.z * th * aspect);
    cam.up = bvh__v3(u.x * th, u.y * th, u.z * th);
    cam.width = width;
    cam.height = height;
    return cam;
}
BVH_API bvh_ray bvh_camera_ray(const bvh_camera *cam, uint32_t x, uint32_t y) {
    bvh_ray ray;
    float sx = 2.0f * ((float)x + 0.5f) / (float)(cam->width ? cam->width : 1) - 1.0f;
    float sy = 1.0f - 2.0f * ((float)y + 0.5f) / (float)(cam->height ? cam->height : 1);
    bvh_vec3 d = bvh__v3(cam->forward.x + sx * cam->right.x + sy * cam->up.x,
                         cam->forward.y + sx * cam->right.y + sy * cam->up.y,
                         cam->forward.z + sx * cam->right.z + sy * cam->up.z);
    ray.origin = cam->eye;
    ray.dir = bvh__normalize(d);
    ray.tmin = 0.0f;
    ray.tmax = BVH_INF;
    return ray;
}

BVH__FP_POP
#endif /* BVH_IMPLEMENTATION_DONE */
#endif /* BVH_IMPLEMENTATION */

/*
MIT License

Copyright (c) 2026 the bvh.h authors

Permission is hereby granted, free of charge, to any person obtaining a copy of this software and
associated documentation files (the "Software"), to deal in the Software without restriction,
including without limitation the rights to use, copy, modify, merge, publish, distribute,
sublicense, and/or sell copies of the Software, and to permit persons to whom the Software is
furnished to do so, subject to the following conditions:

The above copyright notice and this permission notice shall be included in all copies or
substantial portions of the Software.

THE SOFTWARE IS PROVIDED "AS IS", WITHOUT WARRANTY OF ANY KIND, EXPRESS OR IMPLIED, INCLUDING BUT
NOT LIMITED TO THE WARRANTIES OF MERCHANTABILITY, FITNESS FOR A PARTICULAR PURPOSE AND
NONINFRINGEMENT. IN NO EVENT SHALL THE AUTHORS OR COPYRIGHT HOLDERS BE LIABLE FOR ANY CLAIM, DAMAGES
OR OTHER LIABILITY, WHETHER IN AN ACTION OF CONTRACT, TORT OR OTHERWISE, ARISING FROM, OUT OF OR IN
CONNECTION WITH THE SOFTWARE OR THE USE OR OTHER DEALINGS IN THE SOFTWARE.
*/
