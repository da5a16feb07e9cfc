# Finds hypre (Debian's libhypre-dev ships no CMake config or pkg-config file).
# Defines HYPRE_FOUND and the imported target HYPRE::HYPRE.
find_path(HYPRE_INCLUDE_DIR HYPRE.h PATH_SUFFIXES hypre)
find_library(HYPRE_LIBRARY NAMES HYPRE)
include(FindPackageHandleStandardArgs)
find_package_handle_standard_args(HYPRE REQUIRED_VARS HYPRE_LIBRARY HYPRE_INCLUDE_DIR)
if(HYPRE_FOUND AND NOT TARGET HYPRE::HYPRE)
  add_library(HYPRE::HYPRE UNKNOWN IMPORTED)
  set_target_properties(HYPRE::HYPRE PROPERTIES IMPORTED_LOCATION "${HYPRE_LIBRARY}"
                        INTERFACE_INCLUDE_DIRECTORIES "${HYPRE_INCLUDE_DIR}")
  target_link_libraries(HYPRE::HYPRE INTERFACE MPI::MPI_CXX)
endif()
mark_as_advanced(HYPRE_INCLUDE_DIR HYPRE_LIBRARY)
