# bench/plot.gp - the benchmark's plots from the .dat files of `build/bvhbench --plots DIR`
# usage: gnuplot -c bench/plot.gp DIR      (bench/plot.sh DIR checks for gnuplot first)
# Every .dat file starts with a comment saying what it holds; '-' marks a value not measured.
# A builder has the same colour in every plot.
dir = ARGC >= 1 ? ARG1 : "out/bench"
f(name) = dir . "/" . name
have(name) = int(system("[ -f '" . f(name) . "' ] && echo 1 || echo 0"))
builders = "none top-down bottom-up sah-midpoint ploc ploc-parallel embree-low embree-medium embree-high"
colour(name) = sum [k=1:words(builders)] (word(builders, k) eq name ? k : 0)
set linetype 1 lc rgb "#888888"
set linetype 2 lc rgb "#1f77b4"
set linetype 3 lc rgb "#ff7f0e"
set linetype 4 lc rgb "#2ca02c"
set linetype 5 lc rgb "#d62728"
set linetype 6 lc rgb "#9467bd"
set linetype 7 lc rgb "#bcbd22"
set linetype 8 lc rgb "#8c564b"
set linetype 9 lc rgb "#17becf"
set linetype 10 lc rgb "#000000"
set datafile missing "-"
set grid

# ---- 1. build time vs triangles, log-log, one line per builder ------------------------------
# blocks: a header line ("builder" "build_ms" ...) then "triangles build_ms min max scene"
names = system("awk '/\"build_ms\"/ { gsub(/\"/, \"\", $1); printf \"%s \", $1 }' '" . f("build_time.dat") . "'")
set terminal pngcairo size 1000,700 font "sans,11" noenhanced
set output f("build_time.png")
set title "Build time vs triangles (median; bars: min-max)"
set logscale xy
set xlabel "triangles"
set ylabel "build time (ms)"
set key top left box opaque
plot for [i=1:words(names)] f("build_time.dat") index i-1 using 1:2:3:4 with yerrorbars \
         lt (colour(word(names, i)) ? colour(word(names, i)) : 10) pt 7 ps 0.6 notitle, \
     for [i=1:words(names)] f("build_time.dat") index i-1 using 1:2 with linespoints lw 2 pt 7 ps 1.2 \
         lt (colour(word(names, i)) ? colour(word(names, i)) : 10) title word(names, i)

# ---- 2. SAH vs build time: one panel per scene, a labelled point per builder ----------------
stats f("sah_build.dat") using 1 nooutput
n = STATS_blocks
cols = n > 1 ? 2 : 1
rows = (n + cols - 1) / cols
set terminal pngcairo size 640*cols,470*rows font "sans,10" noenhanced
set output f("sah_vs_build.png")
set multiplot layout rows,cols title "SAH (costs 1,0,1) vs build time: lower left is better"
unset logscale
set logscale x
set xlabel "build time (ms, log scale)"
set ylabel "SAH"
set key top right box opaque
set offsets graph 0.1, graph 0.3, graph 0.08, graph 0.08
unset title
# labels alternate above and below their point, so that close points stay readable
do for [i=0:n-1] {
    plot f("sah_build.dat") index i using 1:2:(colour(strcol(3))) with points pt 7 ps 1.5 lc variable \
             title columnheader(1), \
         '' index i using 1:(int($0) % 2 ? 1/0 : $2):3:(colour(strcol(3))) with labels \
             offset char 0.9,0.5 left font ",9" tc variable notitle, \
         '' index i using 1:(int($0) % 2 ? $2 : 1/0):3:(colour(strcol(3))) with labels \
             offset char 0.9,-0.5 left font ",9" tc variable notitle
}
unset multiplot
set offsets 0, 0, 0, 0

# ---- 3. Mrays/s per builder: CPU 1 thread, CPU N threads, OpenCL; diffuse and shadow rays ------
panels = have("mrays_1t.dat") + have("mrays_mt.dat") + have("mrays_cl.dat") + have("mrays_diffuse_1t.dat") \
         + have("mrays_shadow_1t.dat")
if (panels > 0) {
    set terminal pngcairo size 1200,360*panels font "sans,10" noenhanced
    set output f("mrays.png")
    set multiplot layout panels,1 title "Rays per second, per builder and scene (log scale)"
    unset logscale
    set logscale y
    set style data histograms
    set style histogram clustered gap 1
    set style fill solid 0.85 border -1
    set boxwidth 0.9
    unset xlabel
    set ylabel "Mrays/s"
    set xtics scale 0
    set key outside right top vertical autotitle columnheader
    set bmargin 3.5
    set lmargin 10
    do for [file in "mrays_1t.dat mrays_mt.dat mrays_cl.dat mrays_diffuse_1t.dat mrays_shadow_1t.dat"] {
        if (have(file)) {
            cols = system("sed -n 2p '" . f(file) . "' | tr -d '\"'")
            nscenes = int(system("grep -vc '^#' '" . f(file) . "'")) - 1
            set xrange [-0.5:nscenes - 0.5]
            set title system("head -1 '" . f(file) . "' | sed 's/^# //; s/ per scene.*//'")
            plot for [i=2:words(cols)] f(file) using i:xtic(1) \
                 lt (colour(word(cols, i)) ? colour(word(cols, i)) : 10) title word(cols, i)
        }
    }
    unset multiplot
}
