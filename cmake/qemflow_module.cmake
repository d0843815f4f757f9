# qemflow_module(NAME DEPS...): a static library of every .cpp below the calling
# folder. Globbing (with CONFIGURE_DEPENDS) means adding a source file never needs a
# CMake edit; a folder's dependencies are the only thing its CMakeLists says.
function(qemflow_module name)
  file(GLOB_RECURSE sources CONFIGURE_DEPENDS ${CMAKE_CURRENT_SOURCE_DIR}/*.cpp)
  if(sources)
    add_library(${name} STATIC ${sources})
    target_link_libraries(${name} PUBLIC qemflow_warnings ${ARGN})
  else()
    add_library(${name} INTERFACE)
    target_link_libraries(${name} INTERFACE qemflow_warnings ${ARGN})
  endif()
endfunction()

# qemflow_test_suite(NAME DEPS...): one GoogleTest binary of every *_test.cpp in the
# calling folder, each test registered with CTest.
function(qemflow_test_suite name)
  file(GLOB sources CONFIGURE_DEPENDS ${CMAKE_CURRENT_SOURCE_DIR}/*_test.cpp)
  if(NOT sources)
    return()
  endif()
  add_executable(${name} ${sources})
  target_link_libraries(${name} PRIVATE qemflow_test_support GTest::gtest_main ${ARGN})
  gtest_discover_tests(${name} DISCOVERY_TIMEOUT 60 PROPERTIES TIMEOUT 600)
endfunction()
