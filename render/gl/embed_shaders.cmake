# Writes OUTPUT, a C++ header with every shader of SHADER_DIR as a string
# constant, so the renderer reads nothing from disk at run time.
# <stem>.<vert|geom|frag> becomes k<Stem><Vertex|Geometry|Fragment>.
# Usage: cmake -DSHADER_DIR=<dir> -DOUTPUT=<header> -P embed_shaders.cmake
cmake_minimum_required(VERSION 3.22)
if(NOT SHADER_DIR OR NOT OUTPUT)
  message(FATAL_ERROR "embed_shaders.cmake: set SHADER_DIR and OUTPUT")
endif()

file(GLOB _shaders ${SHADER_DIR}/*.vert ${SHADER_DIR}/*.geom ${SHADER_DIR}/*.frag)
list(SORT _shaders)
set(_stages_vert Vertex)
set(_stages_geom Geometry)
set(_stages_frag Fragment)

set(_text "// Generated from render/gl/shaders/ by render/gl/embed_shaders.cmake; do not edit.\n")
string(APPEND _text "#pragma once\n\nnamespace pointillist::render::shaders {\n")
foreach(_shader IN LISTS _shaders)
  get_filename_component(_file ${_shader} NAME)
  get_filename_component(_stem ${_shader} NAME_WE)
  get_filename_component(_ext ${_shader} LAST_EXT)
  string(SUBSTRING "${_ext}" 1 -1 _ext)
  # some_name -> SomeName
  set(_name "")
  string(REPLACE "_" ";" _parts "${_stem}")
  foreach(_part IN LISTS _parts)
    string(SUBSTRING "${_part}" 0 1 _first)
    string(SUBSTRING "${_part}" 1 -1 _rest)
    string(TOUPPER "${_first}" _first)
    string(APPEND _name "${_first}${_rest}")
  endforeach()
  if(NOT _name MATCHES "^[A-Za-z0-9]+$")
    message(FATAL_ERROR "${_shader}: the name must be letters, digits and '_'")
  endif()
  set(_name "k${_name}${_stages_${_ext}}")

  # A raw string literal keeps the text byte for byte, except carriage returns
  # (file(READ) drops them, as the compiler would), NUL bytes and its own
  # delimiter: refused rather than embedded differently.
  file(READ ${_shader} _source)
  file(SIZE ${_shader} _bytes)
  string(LENGTH "${_source}" _length)
  if(NOT _length EQUAL _bytes)
    message(FATAL_ERROR "${_shader}: has carriage returns or NUL bytes; save it as plain text "
      "with Unix line endings")
  endif()
  string(FIND "${_source}" ")glsl\"" _clash)
  if(NOT _clash EQUAL -1)
    message(FATAL_ERROR "${_shader}: contains ')glsl\"', which would end the C++ string")
  endif()
  string(APPEND _text "\n// ${_file}\ninline constexpr char ${_name}[] = R\"glsl(${_source})glsl\";\n")
endforeach()
string(APPEND _text "\n}  // namespace pointillist::render::shaders\n")

file(WRITE ${OUTPUT} "${_text}")
