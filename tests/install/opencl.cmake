# The consumer is strict C11 with warnings as errors, and traces with OpenCL too when CMake finds it.
set_target_properties(consumer PROPERTIES C_STANDARD 11 C_STANDARD_REQUIRED ON C_EXTENSIONS OFF)
target_compile_options(consumer PRIVATE -Wall -Wextra -Wpedantic -Werror)
find_package(OpenCL QUIET)
if(OpenCL_FOUND)
  target_compile_definitions(consumer PRIVATE BVH_HAVE_OPENCL CL_TARGET_OPENCL_VERSION=120)
  target_link_libraries(consumer PRIVATE OpenCL::OpenCL)
endif()
