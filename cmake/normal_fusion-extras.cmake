# Included by find_package(normal_fusion) and by
# find_package(catkin COMPONENTS normal_fusion): normal_fusion's headers need
# C++17 (std::variant, std::optional, std::aligned_alloc).
# A package that asks for an older standard, or none (GCC before 11 defaults
# to C++14), is moved to C++17; a newer standard is kept.
if(NOT DEFINED CMAKE_CXX_STANDARD OR CMAKE_CXX_STANDARD MATCHES "^(98|11|14)$")
  set(CMAKE_CXX_STANDARD 17)
endif()
if(NOT CMAKE_CXX_STANDARD_REQUIRED)
  set(CMAKE_CXX_STANDARD_REQUIRED ON)
endif()
# An explicit older -std= in CMAKE_CXX_FLAGS still wins over the standard
# set above with some compilers: say so rather than fail in the headers.
if(CMAKE_CXX_FLAGS MATCHES "-std=(c|gnu)\\+\\+(98|03|0x|11|1y|14)( |$)")
  message(WARNING "normal_fusion needs C++17, but CMAKE_CXX_FLAGS asks for "
    "an older standard ('${CMAKE_CXX_FLAGS}'): remove that -std= flag")
endif()
